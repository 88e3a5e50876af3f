/*
 * Batched evaluation of an FMI 2.0 Model-Exchange FMU.
 *
 * The Python bridge loads the FMU's shared library, instantiates it and hands this shim
 * the addresses of the FMI functions and the component in one hf_model record. Each
 * exported function below is entered once per batch (or once per stretch of integration
 * steps) and loops over the rows in C, so the per-row cost is that of the FMU itself.
 *
 * Every function returns 0 on success. On failure it returns the FMI status (>= 2) or a
 * negative HF_* code and records in the hf_model which FMI function failed and for which
 * row, so that Python can raise an exception naming both. All arguments are validated in
 * Python before any function here is called.
 *
 * The FMI types are restated here with their FMI 2.0 platform definitions
 * (fmi2Component = void*, fmi2ValueReference = unsigned int, fmi2Real = double,
 * fmi2Boolean = int, fmi2Status = int enum).
 */
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "effects.h"

typedef void *hf_component;
typedef unsigned int hf_vr;
typedef int hf_status;

typedef hf_status (*hf_set_time_fn)(hf_component, double);
typedef hf_status (*hf_set_states_fn)(hf_component, const double *, size_t);
typedef hf_status (*hf_set_real_fn)(hf_component, const hf_vr *, size_t, const double *);
typedef hf_status (*hf_get_real_fn)(hf_component, const hf_vr *, size_t, double *);
typedef hf_status (*hf_get_vector_fn)(hf_component, double *, size_t);
typedef hf_status (*hf_dir_der_fn)(hf_component, const hf_vr *, size_t, const hf_vr *, size_t,
                                   const double *, double *);
typedef hf_status (*hf_completed_fn)(hf_component, int, int *, int *);
typedef int (*hf_correction_fn)(void);

/* fmi2EventInfo restated (five fmi2Boolean, then fmi2Real). */
typedef struct {
    int new_discrete_states_needed;
    int terminate_simulation;
    int nominals_changed;
    int values_changed;
    int next_event_time_defined;
    double next_event_time;
} hf_event_info;

typedef hf_status (*hf_mode_fn)(hf_component);
typedef hf_status (*hf_new_discrete_states_fn)(hf_component, hf_event_info *);

/* Codes of the FMI function that failed (mirrored in shim.py). */
enum {
    HF_FN_NONE = 0,
    HF_FN_SET_TIME = 1,
    HF_FN_SET_STATES = 2,
    HF_FN_SET_REAL = 3,
    HF_FN_GET_REAL = 4,
    HF_FN_GET_DERIVATIVES = 5,
    HF_FN_GET_EVENT_INDICATORS = 6,
    HF_FN_GET_DIR_DER = 7,
    HF_FN_COMPLETED_STEP = 8,
    HF_FN_CORRECTION = 9,
    HF_FN_MALLOC = 10,
    HF_FN_EFFECTS = 11,
    HF_FN_ENTER_EVENT_MODE = 12,
    HF_FN_NEW_DISCRETE_STATES = 13,
    HF_FN_ENTER_CONTINUOUS_TIME_MODE = 14,
    HF_FN_GET_CONTINUOUS_STATES = 15
};

/* Negative return codes that are not FMI statuses. */
#define HF_ERR_CALLBACK (-1)
#define HF_ERR_NO_MEMORY (-2)
#define HF_ERR_NOT_FINITE (-3)

/* Why hf_simulate returned (mirrored in shim.py). */
enum {
    HF_SIM_DONE = 0,
    HF_SIM_STATE_EVENT = 1,  /* an event indicator changed sign within step k */
    HF_SIM_INPUT_EVENT = 2,  /* an event indicator changed sign when the inputs of step k were set */
    HF_SIM_TIME_EVENT = 3,   /* step k would pass the FMU's next time event */
    HF_SIM_STEP_EVENT = 4,   /* fmi2CompletedIntegratorStep asked for event mode after step k */
    HF_SIM_TERMINATE = 5     /* fmi2CompletedIntegratorStep asked to terminate after step k */
};

typedef struct {
    hf_component component;
    hf_set_time_fn set_time;
    hf_set_states_fn set_states;
    hf_set_real_fn set_real;
    hf_get_real_fn get_real;
    hf_get_vector_fn get_derivatives;
    hf_get_vector_fn get_event_indicators;
    hf_dir_der_fn get_directional_derivative; /* NULL when the FMU does not provide it */
    hf_completed_fn completed_integrator_step;
    size_t nx, nu, nz;
    const hf_vr *vr_u;  /* (nu,) value references of the inputs */
    const hf_vr *vr_x;  /* (nx,) value references of the continuous states */
    const hf_vr *vr_dx; /* (nx,) value references of the state derivatives */
    /* optional correction added to the derivatives during integration: the shim copies the
       point into cb_x (nx), cb_u (nu), calls correction() and adds cb_dx (nx) */
    hf_correction_fn correction;
    double *cb_x;
    double *cb_u;
    double *cb_dx;
    /* optional diagnosed effects added to the derivatives during integration, evaluated in C (effects.c):
       the program (effect_code: effect_n_code entries, effect_reals), its output (nx) and work buffer
       (nu + nx), and whether it evaluates the model with changed inputs (set back afterwards) */
    const long long *effect_code;
    size_t effect_n_code;
    const double *effect_reals;
    double *effect_out;
    double *effect_work;
    int effect_sets_inputs;
    /* error report */
    int failed_function;
    long long failed_row;
    int failed_status;
    long long failed_index; /* for HF_ERR_NOT_FINITE: the first state whose derivative is not finite */
    double failed_time;     /* for HF_ERR_NOT_FINITE: the time of the evaluation, s */
    double failed_value;    /* for HF_ERR_NOT_FINITE: that derivative's value (NaN or +-inf) */
    /* the event mode's functions (hf_run_grid); NULL where only the batch functions are used */
    hf_mode_fn enter_event_mode;
    hf_new_discrete_states_fn new_discrete_states;
    hf_mode_fn enter_continuous_time_mode;
    hf_get_vector_fn get_continuous_states;
} hf_model;

#define HF_FAIL(m, fn, row, st)         \
    do {                                \
        (m)->failed_function = (fn);    \
        (m)->failed_row = (long long)(row); \
        (m)->failed_status = (st);      \
        return (st);                    \
    } while (0)

#define HF_CHECK(m, call, fn, row)              \
    do {                                        \
        hf_status st_ = (call);                 \
        if (st_ > 1) HF_FAIL(m, fn, row, st_);  \
    } while (0)

/* ---------------------------------------------------------------- log collection */

/* Messages of the FMU's logger callback, appended to one bounded buffer per model; when it is
   full, the older messages are dropped. */
typedef struct {
    char *text;
    size_t capacity;
    size_t length;
    int worst_status;
    size_t dropped;
} hf_log;

hf_log *hf_log_new(size_t capacity) {
    hf_log *log = (hf_log *)calloc(1, sizeof(hf_log));
    if (!log) return NULL;
    log->text = (char *)calloc(capacity + 1, 1);
    if (!log->text) {
        free(log);
        return NULL;
    }
    log->capacity = capacity;
    return log;
}

void hf_log_free(hf_log *log) {
    if (!log) return;
    free(log->text);
    free(log);
}

/* Copy the collected text into out (NUL-terminated, at most size-1 chars) and clear it. */
size_t hf_log_take(hf_log *log, char *out, size_t size) {
    size_t n = log->length < size - 1 ? log->length : size - 1;
    memcpy(out, log->text, n);
    out[n] = '\0';
    log->length = 0;
    log->text[0] = '\0';
    log->worst_status = 0;
    log->dropped = 0;
    return n;
}

static const char *hf_status_label(int status) {
    switch (status) {
    case 0: return "ok";
    case 1: return "warning";
    case 2: return "discard";
    case 3: return "error";
    case 4: return "fatal";
    case 5: return "pending";
    default: return "unknown";
    }
}

/* The fmi2CallbackLogger: formats the message and appends one line to the log buffer. */
void hf_logger(void *environment, const char *instance_name, int status, const char *category,
               const char *message, ...) {
    hf_log *log = (hf_log *)environment;
    char line[2048];
    int head;
    va_list args;
    if (!log) return;
    head = snprintf(line, sizeof line, "[%s] %s (%s): ", hf_status_label(status),
                    instance_name ? instance_name : "?", category ? category : "");
    if (head < 0) head = 0;
    if ((size_t)head >= sizeof line) head = (int)sizeof line - 1;
    va_start(args, message);
    if (message) vsnprintf(line + head, sizeof line - (size_t)head, message, args);
    va_end(args);
    {
        size_t n = strlen(line);
        if (n + 1 > log->capacity) n = log->capacity - 1;
        if (log->length + n + 1 > log->capacity) {
            /* full: drop the older messages, keep the newest (they explain a failure) */
            log->dropped++;
            log->length = 0;
        }
        memcpy(log->text + log->length, line, n);
        log->length += n;
        log->text[log->length++] = '\n';
        log->text[log->length] = '\0';
    }
    if (status > log->worst_status) log->worst_status = status;
}

void *hf_allocate(size_t count, size_t size) { return calloc(count, size); }

void hf_free(void *pointer) { free(pointer); }

/* ---------------------------------------------------------------- point evaluation */

/* Set time, states and (if any) inputs of one row. */
static int hf_set_point(hf_model *m, double t, const double *x, const double *u, long long row) {
    HF_CHECK(m, m->set_time(m->component, t), HF_FN_SET_TIME, row);
    if (m->nx) HF_CHECK(m, m->set_states(m->component, x, m->nx), HF_FN_SET_STATES, row);
    if (m->nu) HF_CHECK(m, m->set_real(m->component, m->vr_u, m->nu, u), HF_FN_SET_REAL, row);
    return 0;
}

/* HF_ERR_NOT_FINITE (recording the state index, the value and the time) if a derivative in dx (nx,) is
   NaN or infinite, else 0. */
static int hf_check_finite(hf_model *m, const double *dx, double t, long long row) {
    size_t i;
    for (i = 0; i < m->nx; ++i)
        if (!isfinite(dx[i])) {
            m->failed_index = (long long)i;
            m->failed_time = t;
            m->failed_value = dx[i];
            HF_FAIL(m, HF_FN_GET_DERIVATIVES, row, HF_ERR_NOT_FINITE);
        }
    return 0;
}

/* dx (n, nx) = f(t, x, u) for every row. t has stride t_stride (0: one time for all rows).
   A derivative that is not finite stops the loop with HF_ERR_NOT_FINITE at that row. */
int hf_derivatives(hf_model *m, size_t n, const double *t, size_t t_stride, const double *x,
                   const double *u, double *dx) {
    size_t r;
    m->failed_function = HF_FN_NONE;
    for (r = 0; r < n; ++r) {
        const double tr = t[r * t_stride];
        int st = hf_set_point(m, tr, x + r * m->nx, u + r * m->nu, (long long)r);
        if (st) return st;
        HF_CHECK(m, m->get_derivatives(m->component, dx + r * m->nx, m->nx), HF_FN_GET_DERIVATIVES,
                 r);
        if ((st = hf_check_finite(m, dx + r * m->nx, tr, (long long)r))) return st;
    }
    return 0;
}

/* z (n, nz): the event indicators at every row. */
int hf_event_indicators(hf_model *m, size_t n, const double *t, size_t t_stride, const double *x,
                        const double *u, double *z) {
    size_t r;
    m->failed_function = HF_FN_NONE;
    for (r = 0; r < n; ++r) {
        int st = hf_set_point(m, t[r * t_stride], x + r * m->nx, u + r * m->nu, (long long)r);
        if (st) return st;
        HF_CHECK(m, m->get_event_indicators(m->component, z + r * m->nz, m->nz),
                 HF_FN_GET_EVENT_INDICATORS, r);
    }
    return 0;
}

/* y (n, ny): the Real variables vr_y at every row. */
int hf_outputs(hf_model *m, size_t n, const double *t, size_t t_stride, const double *x,
               const double *u, const hf_vr *vr_y, size_t ny, double *y) {
    size_t r;
    m->failed_function = HF_FN_NONE;
    for (r = 0; r < n; ++r) {
        int st = hf_set_point(m, t[r * t_stride], x + r * m->nx, u + r * m->nu, (long long)r);
        if (st) return st;
        HF_CHECK(m, m->get_real(m->component, vr_y, ny, y + r * ny), HF_FN_GET_REAL, r);
    }
    return 0;
}

/* Jacobians from fmi2GetDirectionalDerivative, one call per column:
   dfdx (n, nx, nx) with dfdx[r, i, j] = d f_i / d x_j, dfdu (n, nx, nu) likewise.
   column: nx doubles of work space. */
int hf_jacobians_directional(hf_model *m, size_t n, const double *t, size_t t_stride,
                             const double *x, const double *u, double *dfdx, double *dfdu,
                             double *column) {
    const size_t nx = m->nx, nu = m->nu;
    const double seed = 1.0;
    size_t r, i, j;
    m->failed_function = HF_FN_NONE;
    for (r = 0; r < n; ++r) {
        double *jx = dfdx + r * nx * nx, *ju = dfdu + r * nx * nu;
        int st = hf_set_point(m, t[r * t_stride], x + r * nx, u + r * nu, (long long)r);
        if (st) return st;
        for (j = 0; j < nx; ++j) {
            HF_CHECK(m, m->get_directional_derivative(m->component, m->vr_dx, nx, m->vr_x + j, 1,
                                                      &seed, column),
                     HF_FN_GET_DIR_DER, r);
            for (i = 0; i < nx; ++i) jx[i * nx + j] = column[i];
        }
        for (j = 0; j < nu; ++j) {
            HF_CHECK(m, m->get_directional_derivative(m->component, m->vr_dx, nx, m->vr_u + j, 1,
                                                      &seed, column),
                     HF_FN_GET_DIR_DER, r);
            for (i = 0; i < nx; ++i) ju[i * nu + j] = column[i];
        }
    }
    return 0;
}

/* Central finite difference step for value v with scale s (>0) and relative step rel:
   h = rel * max(|v|, s), rounded so that v + h and v - h are exactly representable offsets. */
static double hf_fd_step(double v, double s, double rel) {
    volatile double plus;
    double h = rel * (fabs(v) > s ? fabs(v) : s);
    plus = v + h;
    return plus - v;
}

/* Jacobians by central finite differences of fmi2GetDerivatives (for FMUs without directional
   derivatives). x_scale (nx,), u_scale (nu,): positive scales (nominal values); rel: the relative
   step. Layout as in hf_jacobians_directional. */
int hf_jacobians_fd(hf_model *m, size_t n, const double *t, size_t t_stride, const double *x,
                    const double *u, const double *x_scale, const double *u_scale, double rel,
                    double *dfdx, double *dfdu) {
    const size_t nx = m->nx, nu = m->nu;
    double *work = (double *)malloc((2 * nx + nu + 2 * nx + 1) * sizeof(double));
    double *xp, *up, *fp, *fm;
    size_t r, i, j;
    int st = 0;
    m->failed_function = HF_FN_NONE;
    if (!work) HF_FAIL(m, HF_FN_MALLOC, 0, HF_ERR_NO_MEMORY);
    xp = work;
    up = xp + nx;
    fp = up + nu;
    fm = fp + nx;
    for (r = 0; r < n && st == 0; ++r) {
        const double tr = t[r * t_stride];
        const double *xr = x + r * nx, *ur = u + r * nu;
        double *jx = dfdx + r * nx * nx, *ju = dfdu + r * nx * nu;
        if (nx) memcpy(xp, xr, nx * sizeof(double));
        if (nu) memcpy(up, ur, nu * sizeof(double));
        if ((st = hf_set_point(m, tr, xr, ur, (long long)r))) break;
        for (j = 0; j < nx && st == 0; ++j) {
            const double h = hf_fd_step(xr[j], x_scale[j], rel);
            xp[j] = xr[j] + h;
            if ((st = m->set_states(m->component, xp, nx)) > 1) { m->failed_function = HF_FN_SET_STATES; break; }
            if ((st = m->get_derivatives(m->component, fp, nx)) > 1) { m->failed_function = HF_FN_GET_DERIVATIVES; break; }
            xp[j] = xr[j] - h;
            if ((st = m->set_states(m->component, xp, nx)) > 1) { m->failed_function = HF_FN_SET_STATES; break; }
            if ((st = m->get_derivatives(m->component, fm, nx)) > 1) { m->failed_function = HF_FN_GET_DERIVATIVES; break; }
            xp[j] = xr[j];
            st = 0;
            for (i = 0; i < nx; ++i) jx[i * nx + j] = (fp[i] - fm[i]) / (2.0 * h);
        }
        if (st) break;
        if (nu && (st = m->set_states(m->component, xr, nx)) > 1) { m->failed_function = HF_FN_SET_STATES; break; }
        st = 0;
        for (j = 0; j < nu && st == 0; ++j) {
            const double h = hf_fd_step(ur[j], u_scale[j], rel);
            up[j] = ur[j] + h;
            if ((st = m->set_real(m->component, m->vr_u, nu, up)) > 1) { m->failed_function = HF_FN_SET_REAL; break; }
            if ((st = m->get_derivatives(m->component, fp, nx)) > 1) { m->failed_function = HF_FN_GET_DERIVATIVES; break; }
            up[j] = ur[j] - h;
            if ((st = m->set_real(m->component, m->vr_u, nu, up)) > 1) { m->failed_function = HF_FN_SET_REAL; break; }
            if ((st = m->get_derivatives(m->component, fm, nx)) > 1) { m->failed_function = HF_FN_GET_DERIVATIVES; break; }
            up[j] = ur[j];
            st = 0;
            for (i = 0; i < nx; ++i) ju[i * nu + j] = (fp[i] - fm[i]) / (2.0 * h);
        }
        if (st) break;
    }
    if (st) {
        m->failed_row = (long long)(r < n ? r : n - 1);
        m->failed_status = st;
    }
    free(work);
    return st;
}

/* ---------------------------------------------------------------- integration */

/* The FMU's derivatives dx at its current time and states with the inputs u (an effect's evaluation). */
static int hf_effect_eval(void *context, const double *u, double *dx) {
    hf_model *m = (hf_model *)context;
    HF_CHECK(m, m->set_real(m->component, m->vr_u, m->nu, u), HF_FN_SET_REAL, -1);
    HF_CHECK(m, m->get_derivatives(m->component, dx, m->nx), HF_FN_GET_DERIVATIVES, -1);
    return 0;
}

/* out (nx,) = program (code, n_code, reals) at (x, u) with the FMU's derivatives f there, the FMU at x; the
   FMU's inputs set back to u after a program that evaluates the model. */
static int hf_program_at(hf_model *m, const long long *code, size_t n_code, const double *reals, const double *x,
                         const double *u, const double *f, double *out, long long row) {
    int st = hf_effects_add(code, n_code, reals, m->nx, m->nu, x, u, f, out, m->effect_work, hf_effect_eval, m);
    if (st == HF_EFFECT_ERR_PROGRAM) HF_FAIL(m, HF_FN_EFFECTS, row, st);
    if (st) {
        m->failed_row = row;
        return st;
    }
    if (m->effect_sets_inputs && m->nu) HF_CHECK(m, m->set_real(m->component, m->vr_u, m->nu, u), HF_FN_SET_REAL, row);
    return 0;
}

/* out = f(t, x, u) + effects(x, u, f) + correction(x, u); the inputs must already be set in the FMU. */
static int hf_rhs(hf_model *m, double t, const double *x, const double *u, double *out,
                  long long row) {
    size_t i;
    HF_CHECK(m, m->set_time(m->component, t), HF_FN_SET_TIME, row);
    HF_CHECK(m, m->set_states(m->component, x, m->nx), HF_FN_SET_STATES, row);
    HF_CHECK(m, m->get_derivatives(m->component, out, m->nx), HF_FN_GET_DERIVATIVES, row);
    if (m->effect_code) {
        int st = hf_program_at(m, m->effect_code, m->effect_n_code, m->effect_reals, x, u, out, m->effect_out, row);
        if (st) return st;
        for (i = 0; i < m->nx; ++i) out[i] += m->effect_out[i];
    }
    if (m->correction) {
        memcpy(m->cb_x, x, m->nx * sizeof(double));
        if (m->nu) memcpy(m->cb_u, u, m->nu * sizeof(double));
        if (m->correction() != 0) HF_FAIL(m, HF_FN_CORRECTION, row, HF_ERR_CALLBACK);
        for (i = 0; i < m->nx; ++i) out[i] += m->cb_dx[i];
    }
    return hf_check_finite(m, out, t, row);
}

/* One classical Runge-Kutta step of size h from (t, x) with the inputs u held; leaves the FMU at
   (t + h, x_new) and, if nz > 0, writes the event indicators there into z_new.
   work: 5 * nx doubles. */
static int hf_rk4(hf_model *m, double t, double h, const double *x, const double *u,
                  double *x_new, double *z_new, double *work, long long row) {
    const size_t nx = m->nx;
    double *k1 = work, *k2 = k1 + nx, *k3 = k2 + nx, *k4 = k3 + nx, *xs = k4 + nx;
    size_t i;
    int st;
    if ((st = hf_rhs(m, t, x, u, k1, row))) return st;
    for (i = 0; i < nx; ++i) xs[i] = x[i] + 0.5 * h * k1[i];
    if ((st = hf_rhs(m, t + 0.5 * h, xs, u, k2, row))) return st;
    for (i = 0; i < nx; ++i) xs[i] = x[i] + 0.5 * h * k2[i];
    if ((st = hf_rhs(m, t + 0.5 * h, xs, u, k3, row))) return st;
    for (i = 0; i < nx; ++i) xs[i] = x[i] + h * k3[i];
    if ((st = hf_rhs(m, t + h, xs, u, k4, row))) return st;
    /* the weights grouped as in hybridfmu.runge_kutta: x + (h/6) (k1 + k4) + (h/3) (k2 + k3) */
    for (i = 0; i < nx; ++i) x_new[i] = x[i] + h / 6.0 * (k1[i] + k4[i]) + h / 3.0 * (k2[i] + k3[i]);
    HF_CHECK(m, m->set_time(m->component, t + h), HF_FN_SET_TIME, row);
    HF_CHECK(m, m->set_states(m->component, x_new, nx), HF_FN_SET_STATES, row);
    if (m->nz)
        HF_CHECK(m, m->get_event_indicators(m->component, z_new, m->nz), HF_FN_GET_EVENT_INDICATORS,
                 row);
    return 0;
}

/* 1 if some event indicator changed its domain (z > 0 versus z <= 0) from a to b. */
static int hf_crossed(const double *a, const double *b, size_t nz) {
    size_t i;
    for (i = 0; i < nz; ++i)
        if ((a[i] > 0.0) != (b[i] > 0.0)) return 1;
    return 0;
}

/* One RK4 step for the event search (see hf_rk4); sets the inputs u first. */
int hf_rk4_step(hf_model *m, double t, double h, const double *x, const double *u, double *x_new,
                double *z_new, double *work) {
    m->failed_function = HF_FN_NONE;
    if (m->nu) HF_CHECK(m, m->set_real(m->component, m->vr_u, m->nu, u), HF_FN_SET_REAL, -1);
    return hf_rk4(m, t, h, x, u, x_new, z_new, work, -1);
}

/* fmi2CompletedIntegratorStep; flags[0] = enterEventMode, flags[1] = terminateSimulation. */
int hf_completed_step(hf_model *m, int *flags) {
    m->failed_function = HF_FN_NONE;
    flags[0] = flags[1] = 0;
    HF_CHECK(m, m->completed_integrator_step(m->component, 1, flags, flags + 1),
             HF_FN_COMPLETED_STEP, -1);
    return 0;
}

/* Fixed-step RK4 on the grid time (T,) with zero-order-hold inputs u (T, nu), starting at step
   k_start with X[k_start] (X is (T, nx)) and the event indicators z_prev (nz,) valid at
   (time[k_start], X[k_start], u[k_start - 1]). Steps until the end of the grid or until an event
   needs the caller; result[0] = reason (HF_SIM_*), result[1] = the step index k concerned
   (for STATE/INPUT/TIME events: X[k] is valid and step k is not done; for STEP/TERMINATE: step k
   is done and X[k + 1] is valid; for DONE: T - 1). z_prev is kept current.
   next_time_event: the FMU's next time event (INFINITY if none). work: 5 * nx + nz doubles. */
int hf_simulate(hf_model *m, size_t T, const double *time, const double *u, size_t k_start,
                double next_time_event, double *X, double *z_prev, double *work,
                long long *result) {
    const size_t nx = m->nx, nu = m->nu, nz = m->nz;
    double *z_new = work + 5 * nx;
    size_t k;
    int st, flags[2];
    m->failed_function = HF_FN_NONE;
    for (k = k_start; k + 1 < T; ++k) {
        const double t = time[k], h = time[k + 1] - time[k];
        const double *uk = u + k * nu;
        const double *xk = X + k * nx;
        double *x1 = X + (k + 1) * nx;
        if (nu && nz) {
            /* new inputs may move an event indicator across zero: an event at time[k] */
            if ((st = hf_set_point(m, t, xk, uk, (long long)k))) return st;
            HF_CHECK(m, m->get_event_indicators(m->component, z_new, nz),
                     HF_FN_GET_EVENT_INDICATORS, (long long)k);
            if (hf_crossed(z_prev, z_new, nz)) {
                result[0] = HF_SIM_INPUT_EVENT;
                result[1] = (long long)k;
                return 0;
            }
            memcpy(z_prev, z_new, nz * sizeof(double));
        } else if (nu) {
            HF_CHECK(m, m->set_real(m->component, m->vr_u, nu, uk), HF_FN_SET_REAL, (long long)k);
        }
        if (time[k + 1] >= next_time_event) {
            result[0] = HF_SIM_TIME_EVENT;
            result[1] = (long long)k;
            return 0;
        }
        if ((st = hf_rk4(m, t, h, xk, uk, x1, z_new, work, (long long)k))) return st;
        if (nz && hf_crossed(z_prev, z_new, nz)) {
            result[0] = HF_SIM_STATE_EVENT;
            result[1] = (long long)k;
            return 0;
        }
        if (nz) memcpy(z_prev, z_new, nz * sizeof(double));
        HF_CHECK(m, m->completed_integrator_step(m->component, 1, flags, flags + 1),
                 HF_FN_COMPLETED_STEP, (long long)k);
        if (flags[1] || flags[0]) {
            result[0] = flags[1] ? HF_SIM_TERMINATE : HF_SIM_STEP_EVENT;
            result[1] = (long long)k;
            return 0;
        }
    }
    result[0] = HF_SIM_DONE;
    result[1] = (long long)(T ? T - 1 : 0);
    return 0;
}

/* ---------------------------------------------------------------- effect terms and their Jacobians */

/* out (nx,) = the installed effect program's terms at (x, u), FMU at t = 0; f: nx doubles of work (the FMU's
   derivatives there). The FMU is left at (x, u). */
static int hf_terms_at(hf_model *m, const double *x, const double *u, double *f, double *out, long long row) {
    int st = hf_set_point(m, 0.0, x, u, row);
    if (st) return st;
    HF_CHECK(m, m->get_derivatives(m->component, f, m->nx), HF_FN_GET_DERIVATIVES, row);
    return hf_program_at(m, m->effect_code, m->effect_n_code, m->effect_reals, x, u, f, out, row);
}

/* The installed effect program's terms and their central differences, row by row (FMU at t = 0), as a hybrid's
   training needs them at every solver stage:
   - terms (n, nx) at (x_r, u_r); with z = [x_r, u_r] and the step s_c = rel (1 + |z_c|), term_x (n, nx, nx) and
     term_u (n, nx, nu) hold column c = (P(z + s_c e_c) - P(z - s_c e_c)) / (2 s_c), P the installed program
     (hybridfmu.model.physics.PhysicsModel's differences);
   - unit_values (n, nx, n_units): unit program k (unit_codes[unit_code_start[k] .. unit_code_start[k + 1]),
     reals from unit_reals[unit_real_start[k]]) at (x_r, u_r) and the FMU's derivatives there (a term with one
     unit coefficient: its regressor);
   - for the rows with |x_r[band_state]| < band (band_state >= 0), pair_values (n, nx, n_pairs): (program 2k -
     program 2k + 1) / (2 pair_steps[k]) of the pair programs (the whole program with one coefficient moved up
     and down by its step), left untouched in the other rows; in_band (n,) = 1 there, else 0.
   work: 2 (nx + nu) + 3 nx doubles. */
int hf_effect_jacobians(hf_model *m, size_t n, const double *x, const double *u, double rel, double *terms,
                        double *term_x, double *term_u, size_t n_units, const long long *unit_codes,
                        const size_t *unit_code_start, const double *unit_reals, const size_t *unit_real_start,
                        double *unit_values, long long band_state, double band, size_t n_pairs,
                        const long long *pair_codes, const size_t *pair_code_start, const double *pair_reals,
                        const size_t *pair_real_start, const double *pair_steps, double *pair_values,
                        unsigned char *in_band, double *work) {
    const size_t nx = m->nx, nu = m->nu, nz = nx + nu;
    double *z = work, *zp = work + nz, *f = zp + nz, *up = f + nx, *down = up + nx;
    size_t r, c, i, k;
    int st;
    if (!m->effect_code) HF_FAIL(m, HF_FN_EFFECTS, -1, HF_EFFECT_ERR_PROGRAM);
    m->failed_function = HF_FN_NONE;
    for (r = 0; r < n; ++r) {
        const long long row = (long long)r;
        memcpy(z, x + r * nx, nx * sizeof(double));
        if (nu) memcpy(z + nx, u + r * nu, nu * sizeof(double));
        for (c = 0; c < nz; ++c) {
            const double step = rel * (1.0 + fabs(z[c]));
            memcpy(zp, z, nz * sizeof(double));
            zp[c] = z[c] + step;
            if ((st = hf_terms_at(m, zp, zp + nx, f, up, row))) return st;
            zp[c] = z[c] - step;
            if ((st = hf_terms_at(m, zp, zp + nx, f, down, row))) return st;
            for (i = 0; i < nx; ++i) {
                const double d = (up[i] - down[i]) / (2.0 * step);
                if (c < nx) term_x[(r * nx + i) * nx + c] = d;
                else term_u[(r * nx + i) * nu + (c - nx)] = d;
            }
        }
        if ((st = hf_terms_at(m, z, z + nx, f, terms + r * nx, row))) return st;
        for (k = 0; k < n_units; ++k) {
            st = hf_program_at(m, unit_codes + unit_code_start[k], unit_code_start[k + 1] - unit_code_start[k],
                               unit_reals + unit_real_start[k], z, z + nx, f, up, row);
            if (st) return st;
            for (i = 0; i < nx; ++i) unit_values[(r * nx + i) * n_units + k] = up[i];
        }
        in_band[r] = band_state >= 0 && fabs(z[band_state]) < band;
        if (!in_band[r]) continue;
        for (k = 0; k < n_pairs; ++k) {
            st = hf_program_at(m, pair_codes + pair_code_start[2 * k],
                               pair_code_start[2 * k + 1] - pair_code_start[2 * k],
                               pair_reals + pair_real_start[2 * k], z, z + nx, f, up, row);
            if (st) return st;
            st = hf_program_at(m, pair_codes + pair_code_start[2 * k + 1],
                               pair_code_start[2 * k + 2] - pair_code_start[2 * k + 1],
                               pair_reals + pair_real_start[2 * k + 1], z, z + nx, f, down, row);
            if (st) return st;
            for (i = 0; i < nx; ++i)
                pair_values[(r * nx + i) * n_pairs + k] = (up[i] - down[i]) / (2.0 * pair_steps[k]);
        }
    }
    return 0;
}

/* ---------------------------------------------------------------- events

The event handling of an open-loop simulation (hybridfmu.fmu.simulate): hf_simulate integrates until an event
needs handling, and hf_run_grid handles it and goes on, so that the whole grid runs in C. State events are located
by bisection on the step fraction (RK4 over the partial step) to the event tolerance, the FMU is integrated just
past the crossing and the event is handled in event mode (fmi2EnterEventMode, fmi2NewDiscreteStates until no new
discrete states, the states read back if the FMU changed them, fmi2EnterContinuousTimeMode); time events
(nextEventTime), input events (new inputs move an indicator across zero) and step events
(fmi2CompletedIntegratorStep) likewise. Every event handled is appended to the log of the hf_events record; a
terminate request, too many events within one sample interval, a time event announced in the past, non-finite
states after an event or an event iteration that does not settle end the run with the outcome recorded there. */

/* What happened: the event kinds of the log (mirrored in simulate.py). */
enum {
    HF_EV_SETTLE = 0,     /* the event iteration at the start (logged only if the states changed) */
    HF_EV_INPUT = 1,
    HF_EV_STATE = 2,
    HF_EV_TIME = 3,
    HF_EV_STEP = 4
};

/* How hf_run_grid ended (hf_events.outcome; mirrored in simulate.py). */
enum {
    HF_OUT_DONE = 0,
    HF_OUT_PAUSE = 1,             /* the log is nearly full: read it, empty it and call again from *k_out */
    HF_OUT_TERMINATE = 2,         /* the FMU asked to terminate (terminate_source, outcome_time, outcome_x) */
    HF_OUT_TOO_MANY_EVENTS = 3,   /* more than max_events within the interval ending at outcome_value */
    HF_OUT_TIME_EVENT_PAST = 4,   /* nextEventTime outcome_value is not after the current time outcome_time */
    HF_OUT_NONFINITE_STATES = 5,  /* the FMU set non-finite states (outcome_x) at the event at outcome_time */
    HF_OUT_NO_CONVERGENCE = 6     /* the event iteration at outcome_time did not settle in max_iterations */
};

/* Which function asked to terminate. */
enum { HF_TERM_NEW_DISCRETE_STATES = 1, HF_TERM_COMPLETED_STEP = 2 };

/* Returned by the event functions below when they stopped with an outcome (not an FMI failure). */
#define HF_STOP (-10)

typedef struct {
    double tolerance_s;       /* width of the bracket that locates a state event */
    long long max_events;     /* the most events handled within one sample interval */
    long long max_iterations; /* the most fmi2NewDiscreteStates calls of one event iteration */
    double next_time_event;   /* the FMU's next time event (INFINITY if none); kept current */
    /* log: count entries written (at most capacity); total counts every event handled */
    size_t capacity, count;
    long long total;
    double *log_time;
    int *log_kind;
    int *log_reinit;              /* the FMU changed the states at the event */
    unsigned char *log_crossed;   /* (capacity, nz): the indicators that changed sign (input and state events) */
    /* outcome */
    int outcome;
    int terminate_source;
    int terminate_kind;           /* the event kind whose iteration asked to terminate (or -1) */
    int terminate_reinit;
    double outcome_time;
    double outcome_value;
    double *outcome_x;            /* (nx,) */
} hf_events;

static void hf_ev_log(hf_events *ev, size_t nz, int kind, double t, int reinit, const double *z_a,
                      const double *z_b) {
    ev->total += 1;
    if (ev->count < ev->capacity) {
        size_t i = ev->count++, j;
        ev->log_time[i] = t;
        ev->log_kind[i] = kind;
        ev->log_reinit[i] = reinit;
        for (j = 0; j < nz; ++j) ev->log_crossed[i * nz + j] = z_a && z_b ? ((z_a[j] > 0.0) != (z_b[j] > 0.0)) : 0;
    }
}

static int hf_ev_stop(hf_events *ev, int outcome, double t, double value, const double *x, size_t nx) {
    ev->outcome = outcome;
    ev->outcome_time = t;
    ev->outcome_value = value;
    if (x && ev->outcome_x) memcpy(ev->outcome_x, x, nx * sizeof(double));
    return HF_STOP;
}

/* Event mode at (t, x, u): x (nx) becomes the states after the event, z_out (nz) the indicators there. kind and the
   indicators before/after the crossing (z_a, z_b; NULL: none) go to the log (HF_EV_SETTLE only if the FMU changed
   the states). */
static int hf_handle_event(hf_model *m, hf_events *ev, double t, double *x, const double *u, int kind,
                           const double *z_a, const double *z_b, double *z_out) {
    hf_event_info info;
    long long it;
    int changed = 0, reinit, st;
    size_t i;
    if ((st = hf_event_indicators(m, 1, &t, 0, x, u, z_out))) return st; /* sets time, states and inputs */
    HF_CHECK(m, m->enter_event_mode(m->component), HF_FN_ENTER_EVENT_MODE, -1);
    memset(&info, 0, sizeof info);
    for (it = 0; it < ev->max_iterations; ++it) {
        memset(&info, 0, sizeof info);
        HF_CHECK(m, m->new_discrete_states(m->component, &info), HF_FN_NEW_DISCRETE_STATES, -1);
        changed = changed || info.values_changed;
        if (info.terminate_simulation || !info.new_discrete_states_needed) break;
    }
    if (it == ev->max_iterations) return hf_ev_stop(ev, HF_OUT_NO_CONVERGENCE, t, 0.0, NULL, 0);
    reinit = changed && m->nx;
    if (reinit) {
        HF_CHECK(m, m->get_continuous_states(m->component, x, m->nx), HF_FN_GET_CONTINUOUS_STATES, -1);
        for (i = 0; i < m->nx; ++i)
            if (!isfinite(x[i])) return hf_ev_stop(ev, HF_OUT_NONFINITE_STATES, t, 0.0, x, m->nx);
    }
    if (kind != HF_EV_SETTLE || reinit) hf_ev_log(ev, m->nz, kind, t, reinit, z_a, z_b);
    if (info.terminate_simulation) {
        ev->terminate_source = HF_TERM_NEW_DISCRETE_STATES;
        ev->terminate_kind = kind;
        ev->terminate_reinit = reinit;
        return hf_ev_stop(ev, HF_OUT_TERMINATE, t, 0.0, x, m->nx);
    }
    ev->next_time_event = info.next_event_time_defined ? info.next_event_time : INFINITY;
    HF_CHECK(m, m->enter_continuous_time_mode(m->component), HF_FN_ENTER_CONTINUOUS_TIME_MODE, -1);
    return hf_event_indicators(m, 1, &t, 0, x, u, z_out);
}

/* fmi2CompletedIntegratorStep at the accepted point (t, x); a step event if the FMU asks for one. */
static int hf_accept_step(hf_model *m, hf_events *ev, double t, double *x, const double *u, double *z) {
    int flags[2] = {0, 0};
    HF_CHECK(m, m->completed_integrator_step(m->component, 1, flags, flags + 1), HF_FN_COMPLETED_STEP, -1);
    if (flags[1]) {
        ev->terminate_source = HF_TERM_COMPLETED_STEP;
        ev->terminate_kind = -1;
        return hf_ev_stop(ev, HF_OUT_TERMINATE, t, 0.0, x, m->nx);
    }
    if (flags[0]) return hf_handle_event(m, ev, t, x, u, HF_EV_STEP, NULL, NULL, z);
    return 0;
}

/* One RK4 step from (t_a, x) towards t_stop, cut short at the first state event, which is then handled: x and z
   become the states and indicators where the step ended (*t_end); *handled = an event was handled.
   work: 11 nx + 4 nz doubles. */
static int hf_event_step(hf_model *m, hf_events *ev, double t_a, double *x, double t_stop, const double *u,
                         double *z, double *t_end, int *handled, double *work) {
    const size_t nx = m->nx, nz = m->nz;
    double *x_b = work, *x_m = x_b + nx, *x_hi = x_m + nx, *rk = x_hi + nx;
    double *z_b = rk + 5 * nx, *z_m = z_b + nz, *z_hi = z_m + nz, *z_a = z_hi + nz;
    const double span = t_stop - t_a;
    const long long before = ev->total;
    double lo = 0.0, hi = 1.0, t_b, tol, t_e;
    int st, flags[2] = {0, 0};
    if ((st = hf_rk4_step(m, t_a, span, x, u, x_b, z_b, rk))) return st;
    if (!nz || !hf_crossed(z, z_b, nz)) {
        memcpy(x, x_b, nx * sizeof(double));
        if (nz) memcpy(z, z_b, nz * sizeof(double));
        if ((st = hf_accept_step(m, ev, t_stop, x, u, z))) return st;
        *t_end = t_stop;
        *handled = ev->total > before;
        return 0;
    }
    /* bisection on the step's fraction for the first point where an indicator left its domain at t_a */
    memcpy(x_hi, x_b, nx * sizeof(double));
    memcpy(z_hi, z_b, nz * sizeof(double));
    t_b = t_a + span;
    tol = fmax(ev->tolerance_s, 4.0 * DBL_EPSILON * fmax(1.0, fabs(t_b)));
    while ((hi - lo) * span > tol) {
        const double mid = 0.5 * (lo + hi);
        if ((st = hf_rk4_step(m, t_a, mid * span, x, u, x_m, z_m, rk))) return st;
        if (hf_crossed(z, z_m, nz)) {
            hi = mid;
            memcpy(x_hi, x_m, nx * sizeof(double));
            memcpy(z_hi, z_m, nz * sizeof(double));
        } else {
            lo = mid;
        }
    }
    t_e = hi < 1.0 ? t_a + hi * span : t_b;
    if ((st = hf_event_indicators(m, 1, &t_e, 0, x_hi, u, z_m))) return st; /* the FMU at the accepted point */
    /* event mode follows anyway: of fmi2CompletedIntegratorStep only a terminate request matters */
    HF_CHECK(m, m->completed_integrator_step(m->component, 1, flags, flags + 1), HF_FN_COMPLETED_STEP, -1);
    if (flags[1]) {
        ev->terminate_source = HF_TERM_COMPLETED_STEP;
        ev->terminate_kind = -1;
        return hf_ev_stop(ev, HF_OUT_TERMINATE, t_e, 0.0, x_hi, nx);
    }
    memcpy(z_a, z, nz * sizeof(double));
    memcpy(x, x_hi, nx * sizeof(double));
    if ((st = hf_handle_event(m, ev, t_e, x, u, HF_EV_STATE, z_a, z_hi, z))) return st;
    *t_end = t_e;
    *handled = 1;
    return 0;
}

/* Integrate from (t_a, x) to t_b with the inputs u held, handling in time order every time event and state event
   on the way and a time event due at t_b: x and z become the states and indicators at t_b. */
static int hf_integrate_interval(hf_model *m, hf_events *ev, double t_a, double *x, double t_b, const double *u,
                                 double *z, double *work) {
    long long events = 0;
    int st, handled;
    for (;;) {
        if (ev->next_time_event <= t_a) {
            if (events >= ev->max_events) return hf_ev_stop(ev, HF_OUT_TOO_MANY_EVENTS, t_a, t_b, NULL, 0);
            events += 1;
            if ((st = hf_handle_event(m, ev, t_a, x, u, HF_EV_TIME, NULL, NULL, z))) return st;
            if (ev->next_time_event <= t_a)
                return hf_ev_stop(ev, HF_OUT_TIME_EVENT_PAST, t_a, ev->next_time_event, NULL, 0);
            continue;
        }
        if (t_b - t_a <= 4.0 * DBL_EPSILON * fmax(1.0, fabs(t_b))) return 0;
        {
            double t_end = t_a;
            handled = 0;
            if ((st = hf_event_step(m, ev, t_a, x, fmin(ev->next_time_event, t_b), u, z, &t_end, &handled, work)))
                return st;
            t_a = t_end;
        }
        if (handled) {
            if (events >= ev->max_events) return hf_ev_stop(ev, HF_OUT_TOO_MANY_EVENTS, t_a, t_b, NULL, 0);
            events += 1;
        }
    }
}

/* The event iteration at the start (t0, x (nx), u0): x and z (nz) become the states and indicators after it
   (logged only if the FMU changed the states). */
int hf_settle(hf_model *m, hf_events *ev, double t0, double *x, const double *u0, double *z) {
    m->failed_function = HF_FN_NONE;
    ev->outcome = HF_OUT_DONE;
    return hf_handle_event(m, ev, t0, x, u0, HF_EV_SETTLE, NULL, NULL, z);
}

/* The open-loop simulation on the grid time (T,) with the inputs u (T, nu) held per sample, from step k_start
   (X (T, nx) valid up to row k_start, z_prev (nz) the indicators there), handling every event (see above).
   Returns 0 with ev->outcome set (HF_OUT_DONE: X complete; HF_OUT_PAUSE: the log is nearly full, X valid up to
   row *k_out, call again from there after reading it; the others: the run ended, see hf_events), or an FMI
   status / HF_ERR_* code. work: 16 nx + 6 nz + 1 doubles. */
int hf_run_grid(hf_model *m, hf_events *ev, size_t T, const double *time, const double *u, size_t k_start,
                double *X, double *z_prev, double *work, long long *k_out) {
    const size_t nx = m->nx, nu = m->nu, nz = m->nz;
    double *sim_work = work, *z_new = work + 5 * nx, *step_work = z_new + nz + 1;
    long long result[2];
    size_t k = k_start;
    int st;
    m->failed_function = HF_FN_NONE;
    ev->outcome = HF_OUT_DONE;
    while (k + 1 < T) {
        if (ev->capacity - ev->count < (size_t)ev->max_events + 2) {
            ev->outcome = HF_OUT_PAUSE;
            *k_out = (long long)k;
            return 0;
        }
        if ((st = hf_simulate(m, T, time, u, k, ev->next_time_event, X, z_prev, sim_work, result))) return st;
        k = (size_t)result[1];
        switch ((int)result[0]) {
        case HF_SIM_DONE:
            *k_out = (long long)(T - 1);
            return 0;
        case HF_SIM_INPUT_EVENT:
            if ((st = hf_event_indicators(m, 1, &time[k], 0, X + k * nx, u + k * nu, z_new))) return st;
            {
                double *z_before = step_work + 11 * nx + 4 * nz; /* a copy: hf_handle_event writes z_prev */
                memcpy(z_before, z_prev, nz * sizeof(double));
                st = hf_handle_event(m, ev, time[k], X + k * nx, u + k * nu, HF_EV_INPUT, z_before, z_new, z_prev);
            }
            break;
        case HF_SIM_STATE_EVENT:
        case HF_SIM_TIME_EVENT:
            memcpy(X + (k + 1) * nx, X + k * nx, nx * sizeof(double));
            st = hf_integrate_interval(m, ev, time[k], X + (k + 1) * nx, time[k + 1], u + k * nu, z_prev, step_work);
            k += 1;
            break;
        case HF_SIM_STEP_EVENT:
            st = hf_handle_event(m, ev, time[k + 1], X + (k + 1) * nx, u + k * nu, HF_EV_STEP, NULL, NULL, z_prev);
            k += 1;
            break;
        case HF_SIM_TERMINATE:
            ev->terminate_source = HF_TERM_COMPLETED_STEP;
            ev->terminate_kind = -1;
            st = hf_ev_stop(ev, HF_OUT_TERMINATE, time[k + 1], 0.0, X + (k + 1) * nx, nx);
            break;
        default:
            return HF_ERR_CALLBACK;
        }
        if (st == HF_STOP) {
            *k_out = (long long)k;
            return 0;
        }
        if (st) return st;
    }
    *k_out = (long long)(T ? T - 1 : 0);
    return 0;
}

/* ---------------------------------------------------------------- neural FMU rollout */

/* Where W_out starts in a neural FMU's params (layout in hf_neural_stage). */
static size_t hf_neural_output_offset(size_t nx, size_t n_act, const size_t *widths) {
    size_t offset = 2 * nx * widths[0], l;
    for (l = 1; l < n_act; ++l) offset += widths[l - 1] * widths[l] + widths[l];
    return offset;
}

/* Whether a neural FMU's ANN adds nothing: W_out and b_out all zero (its gates closed). */
static int hf_neural_is_silent(size_t nx, size_t n_act, const size_t *widths, const double *params) {
    const double *w = params + hf_neural_output_offset(nx, n_act, widths);
    size_t i, n = widths[n_act - 1] * nx + nx;
    for (i = 0; i < n; ++i)
        if (w[i] != 0.0) return 0;
    return 1;
}

/* One stage of a neural FMU in its fused form (hybridfmu.model.neural_fmu.FusedDerivative) for one row:
     a_0 = tanh(z + [x, f] W_xd),  a_l = tanh(b_l + a_(l-1) W_l),  y = f * g + b_out + a_L W_out,
   f = f(x, u) the FMU's derivatives (already in f). params: W_xd (2 nx, H_0), then per hidden layer
   W_l (H_(l-1), H_l) and b_l (H_l), then W_out (H_L, nx), b_out (nx), g (nx), all row-major.
   act: H_0 + ... + H_L doubles, receives the activations layer after layer. silent != 0 (the caller found
   W_out and b_out all zero, and records no activations): y = f * g + b_out without the hidden layers, the same
   values (a zero sign aside). */
static void hf_neural_stage(size_t nx, const double *x, const double *f, const double *z, size_t n_act,
                            const size_t *widths, const double *params, double *act, double *y, int silent) {
    const double *p = params, *w;
    double *a = act, *b;
    size_t width = widths[0], next, i, j, l;
    if (silent) {
        p = params + hf_neural_output_offset(nx, n_act, widths) + widths[n_act - 1] * nx; /* b_out, then g */
        for (i = 0; i < nx; ++i) y[i] = f[i] * p[nx + i] + p[i];
        return;
    }
    for (j = 0; j < width; ++j) a[j] = z[j];
    for (i = 0; i < nx; ++i) {
        w = p + i * width;
        for (j = 0; j < width; ++j) a[j] += x[i] * w[j];
    }
    for (i = 0; i < nx; ++i) {
        w = p + (nx + i) * width;
        for (j = 0; j < width; ++j) a[j] += f[i] * w[j];
    }
    for (j = 0; j < width; ++j) a[j] = tanh(a[j]);
    p += 2 * nx * width;
    for (l = 1; l < n_act; ++l) {
        next = widths[l];
        b = a + width;
        w = p;
        p += width * next;
        for (j = 0; j < next; ++j) b[j] = p[j];
        for (i = 0; i < width; ++i)
            for (j = 0; j < next; ++j) b[j] += a[i] * w[i * next + j];
        for (j = 0; j < next; ++j) b[j] = tanh(b[j]);
        p += next;
        a = b;
        width = next;
    }
    w = p;
    p += width * nx; /* b_out, then g */
    for (i = 0; i < nx; ++i) y[i] = f[i] * p[nx + i] + p[i];
    for (j = 0; j < width; ++j)
        for (i = 0; i < nx; ++i) y[i] += a[j] * w[j * nx + i];
}

/* How a recorded rollout gets the FMU's Jacobians: none (gradient-free), directional derivatives, or
   central finite differences with the scales and relative step below. */
typedef struct {
    int method; /* 0 none, 1 directional, 2 finite differences */
    const double *x_scale, *u_scale;
    double rel;
    double *dfdx, *dfdu, *column; /* work: nx * nx, nx * nu, nx doubles */
} hf_jacobian_source;

/* y = the neural FMU's derivative at (x, u) with first-layer input term z, for one row (FMU at t = 0).
   With a Jacobian source (method > 0) also records xf = [x, f] (2 nx) and jac = [df/dx, df/du]
   (nx, nx + nu, row-major); f: nx doubles of work (or xf + nx). */
static int hf_neural_rhs(hf_model *m, const double *x, const double *u, const double *z, size_t n_act,
                         const size_t *widths, const double *params, double *f, double *act, double *y,
                         hf_jacobian_source *jac_source, double *xf, double *jac, long long row, int silent) {
    const size_t nx = m->nx, nu = m->nu;
    const double t0 = 0.0;
    size_t i, j;
    int st = hf_set_point(m, 0.0, x, u, row);
    if (st) return st;
    if (jac_source && jac_source->method) f = xf + nx;
    HF_CHECK(m, m->get_derivatives(m->component, f, nx), HF_FN_GET_DERIVATIVES, row);
    if (m->effect_code) { /* a hybrid's physical layer: f = the FMU's derivatives + the diagnosed effects */
        if (jac_source && jac_source->method) HF_FAIL(m, HF_FN_EFFECTS, row, HF_EFFECT_ERR_PROGRAM);
        st = hf_program_at(m, m->effect_code, m->effect_n_code, m->effect_reals, x, u, f, m->effect_out, row);
        if (st) return st;
        for (i = 0; i < nx; ++i) f[i] += m->effect_out[i];
    }
    if ((st = hf_check_finite(m, f, 0.0, row))) return st;
    hf_neural_stage(nx, x, f, z, n_act, widths, params, act, y, silent);
    if (!jac_source || !jac_source->method) return 0;
    memcpy(xf, x, nx * sizeof(double));
    if (jac_source->method == 1)
        st = hf_jacobians_directional(m, 1, &t0, 0, x, u, jac_source->dfdx, jac_source->dfdu, jac_source->column);
    else
        st = hf_jacobians_fd(m, 1, &t0, 0, x, u, jac_source->x_scale, jac_source->u_scale, jac_source->rel,
                             jac_source->dfdx, jac_source->dfdu);
    if (st) {
        m->failed_row = row;
        return st;
    }
    for (i = 0; i < nx; ++i) {
        for (j = 0; j < nx; ++j) jac[i * (nx + nu) + j] = jac_source->dfdx[i * nx + j];
        for (j = 0; j < nu; ++j) jac[i * (nx + nu) + nx + j] = jac_source->dfdu[i * nu + j];
    }
    return 0;
}

/* The rollout shared by hf_neural_rollout and hf_neural_forward_record (records when jac_source->method > 0:
   per stage j = k * S + s, S = 4 for RK4 and 1 for Euler, and row r: xf_rec (R, B, 2 nx), jac_rec
   (R, B, nx, nx + nu), act_rec (R, B, H_0 + ... + H_L); clamped (n_steps, B) = 1 where the end stop held the
   step's new state). row_steps (batch,) or NULL: each row's own number of steps, after which its state is
   held. work: 6 * nx + batch * nx + H_0 + ... + H_L doubles. */
static int hf_neural_loop(hf_model *m, size_t n_steps, size_t batch, double h, int rk4, const double *x0,
                          const double *u_grid, const double *u_half, const double *z_grid, const double *z_half,
                          size_t n_act, const size_t *widths, const double *params, long long i_pos,
                          long long i_rate, double lower, double upper, double *states, double *work,
                          size_t *steps_done, const size_t *row_steps, hf_jacobian_source *jac_source,
                          double *xf_rec, double *jac_rec, double *act_rec, unsigned char *clamped) {
    const size_t nx = m->nx, nu = m->nu, h0 = widths[0], stages = rk4 ? 4 : 1;
    const int record = jac_source && jac_source->method;
    /* a gradient-free rollout of an ANN that adds nothing skips its hidden layers (nothing records them) */
    const int silent = !record && hf_neural_is_silent(nx, n_act, widths, params);
    size_t width_sum = 0, k, r, i, l, s;
    for (l = 0; l < n_act; ++l) width_sum += widths[l];
    double *kk[4], *xs = work + 4 * nx, *f = xs + nx, *next = f + nx, *act = next + batch * nx;
    int st;
    for (s = 0; s < 4; ++s) kk[s] = work + s * nx;
    m->failed_function = HF_FN_NONE;
    memcpy(states, x0, batch * nx * sizeof(double));
    *steps_done = 0;
    for (k = 0; k < n_steps; ++k) {
        const double *x_k = states + k * batch * nx;
        int finite = 1;
        for (r = 0; r < batch; ++r) {
            const double *x = x_k + r * nx;
            const double *us[4], *zs[4], *xin[4];
            double *x_new = next + r * nx;
            const long long row = (long long)r;
            if (row_steps && k >= row_steps[r]) { /* the row's own steps are done: hold its state */
                memcpy(x_new, x, nx * sizeof(double));
                continue;
            }
            us[0] = u_grid + (k * batch + r) * nu;
            zs[0] = z_grid + (k * batch + r) * h0;
            if (rk4) {
                us[1] = us[2] = u_half + (k * batch + r) * nu;
                zs[1] = zs[2] = z_half + (k * batch + r) * h0;
                us[3] = us[0] + batch * nu;
                zs[3] = zs[0] + batch * h0;
            }
            for (s = 0; s < stages; ++s) {
                const size_t j = (k * stages + s) * batch + r;
                if (s == 0) {
                    xin[0] = x;
                } else {
                    const double c = s == 3 ? h : 0.5 * h;
                    for (i = 0; i < nx; ++i) xs[i] = x[i] + c * kk[s - 1][i];
                    xin[s] = xs;
                }
                st = hf_neural_rhs(m, xin[s], us[s], zs[s], n_act, widths, params, f,
                                   record ? act_rec + j * width_sum : act, kk[s], jac_source,
                                   record ? xf_rec + j * 2 * nx : NULL, record ? jac_rec + j * nx * (nx + nu) : NULL,
                                   row, silent);
                if (st) return st;
            }
            if (rk4)
                for (i = 0; i < nx; ++i)
                    x_new[i] = x[i] + h / 6.0 * (kk[0][i] + kk[3][i]) + h / 3.0 * (kk[1][i] + kk[2][i]);
            else
                for (i = 0; i < nx; ++i) x_new[i] = x[i] + h * kk[0][i];
            if (clamped) clamped[k * batch + r] = 0;
            if (i_pos >= 0 && (x_new[i_pos] <= lower || x_new[i_pos] >= upper)) {
                x_new[i_pos] = x_new[i_pos] < lower ? lower : (x_new[i_pos] > upper ? upper : x_new[i_pos]);
                x_new[i_rate] = 0.0;
                if (clamped) clamped[k * batch + r] = 1;
            }
            for (i = 0; i < nx; ++i)
                if (!isfinite(x_new[i])) finite = 0;
        }
        if (!finite) return 0;
        memcpy(states + (k + 1) * batch * nx, next, batch * nx * sizeof(double));
        *steps_done = k + 1;
    }
    return 0;
}

/* Gradient-free open-loop rollout of a neural FMU, `batch` rows side by side, n_steps steps of size h on the
   sample grid: classical RK4 (rk4 != 0; inputs at the step's ends from u_grid/z_grid, at its middle from
   u_half/z_half) or explicit Euler. Time-major inputs: x0 (batch, nx), u_grid (n_steps + 1, batch, nu),
   u_half (n_steps, batch, nu), z_grid (n_steps + 1, batch, H_0), z_half (n_steps, batch, H_0); weights as in
   hf_neural_stage. End stop (i_pos >= 0): after a step, a position at or beyond [lower, upper] is clamped and
   its rate set to 0. states (n_steps + 1, batch, nx): row 0 = x0, then each step while every state stays
   finite; *steps_done = the steps written (n_steps unless a state became non-finite). row_steps (batch,) or
   NULL: each row's own number of steps (at most n_steps), after which its state is held. With an effect program
   installed (a hybrid's physical layer), f is the FMU's derivatives plus the program's terms (effects.c); a
   recording rollout (hf_neural_forward_record) refuses one (its Jacobians would miss the terms).
   work: 6 * nx + batch * nx + H_0 + ... + H_L doubles. */
int hf_neural_rollout(hf_model *m, size_t n_steps, size_t batch, double h, int rk4, const double *x0,
                      const double *u_grid, const double *u_half, const double *z_grid, const double *z_half,
                      size_t n_act, const size_t *widths, const double *params, long long i_pos,
                      long long i_rate, double lower, double upper, double *states, double *work,
                      size_t *steps_done, const size_t *row_steps) {
    return hf_neural_loop(m, n_steps, batch, h, rk4, x0, u_grid, u_half, z_grid, z_half, n_act, widths, params,
                          i_pos, i_rate, lower, upper, states, work, steps_done, row_steps, NULL, NULL, NULL, NULL,
                          NULL);
}

/* hf_neural_rollout for training: records what the reverse sweep (hf_neural_backward) needs, see
   hf_neural_loop. jac_method: 1 directional derivatives, 2 central finite differences (x_scale (nx),
   u_scale (nu), rel as in hf_jacobians_fd). work: 7 * nx + nx * (nx + nu) + batch * nx + H_0 + ... + H_L
   doubles. */
int hf_neural_forward_record(hf_model *m, size_t n_steps, size_t batch, double h, int rk4, const double *x0,
                             const double *u_grid, const double *u_half, const double *z_grid,
                             const double *z_half, size_t n_act, const size_t *widths, const double *params,
                             long long i_pos, long long i_rate, double lower, double upper, double *states,
                             double *work, size_t *steps_done, int jac_method, const double *x_scale,
                             const double *u_scale, double rel, double *xf_rec, double *jac_rec, double *act_rec,
                             unsigned char *clamped) {
    const size_t nx = m->nx, nu = m->nu;
    hf_jacobian_source source;
    source.method = jac_method;
    source.x_scale = x_scale;
    source.u_scale = u_scale;
    source.rel = rel;
    source.dfdx = work;
    source.dfdu = work + nx * nx;
    source.column = work + nx * (nx + nu);
    return hf_neural_loop(m, n_steps, batch, h, rk4, x0, u_grid, u_half, z_grid, z_half, n_act, widths, params,
                          i_pos, i_rate, lower, upper, states, work + nx * (nx + nu) + nx, steps_done, NULL,
                          &source, xf_rec, jac_rec, act_rec, clamped);
}

/* Reverse sweep of one stage (record j of row r) for the output gradient gy (nx): accumulates the weight
   gradients into g_params (layout of params), adds the input gradient to gu (nu) and the first layer's
   input-term gradient to gz (H_0), and writes the state gradient to gx (nx).
   work: 3 * nx + 2 * max(H) doubles. */
static void hf_neural_stage_backward(size_t nx, size_t nu, const double *xf, const double *jac, const double *act,
                                     size_t n_act, const size_t *widths, const double *params, double *g_params,
                                     const double *gy, double *gx, double *gu, double *gz, double *work) {
    size_t width_max = 0, offsets[64], p_off[64], l, i, j, width, prev;
    size_t p = 2 * nx * widths[0];
    const double *f = xf + nx, *a, *w;
    double *g_h, *g_a, *g_xf = work, *g_fmu = work + 2 * nx;
    offsets[0] = 0;
    for (l = 0; l < n_act; ++l) {
        if (widths[l] > width_max) width_max = widths[l];
        if (l > 0) {
            offsets[l] = offsets[l - 1] + widths[l - 1];
            p_off[l] = p; /* W_l, then b_l */
            p += widths[l - 1] * widths[l] + widths[l];
        }
    }
    g_h = work + 3 * nx;
    g_a = g_h + width_max;
    /* output layer: y = f * g + b_out + a_L W_out */
    width = widths[n_act - 1];
    a = act + offsets[n_act - 1];
    w = params + p;
    {
        double *gw = g_params + p, *gb = gw + width * nx, *gg = gb + nx;
        const double *g = params + p + width * nx + nx;
        for (j = 0; j < width; ++j) {
            double acc = 0.0;
            for (i = 0; i < nx; ++i) {
                gw[j * nx + i] += a[j] * gy[i];
                acc += gy[i] * w[j * nx + i];
            }
            g_h[j] = acc;
        }
        for (i = 0; i < nx; ++i) {
            gb[i] += gy[i];
            gg[i] += f[i] * gy[i];
            g_fmu[i] = gy[i] * g[i];
        }
    }
    /* hidden layers, last to first */
    for (l = n_act - 1; l > 0; --l) {
        width = widths[l];
        prev = widths[l - 1];
        a = act + offsets[l];
        for (j = 0; j < width; ++j) g_a[j] = g_h[j] - g_h[j] * a[j] * a[j];
        {
            const double *wl = params + p_off[l], *a_prev = act + offsets[l - 1];
            double *gw = g_params + p_off[l], *gb = gw + prev * width;
            for (j = 0; j < width; ++j) gb[j] += g_a[j];
            for (i = 0; i < prev; ++i) {
                double acc = 0.0;
                for (j = 0; j < width; ++j) {
                    gw[i * width + j] += a_prev[i] * g_a[j];
                    acc += g_a[j] * wl[i * width + j];
                }
                g_h[i] = acc; /* now the gradient of layer l-1's output */
            }
        }
    }
    /* first layer: a_0 = tanh(z + xf W_xd) */
    width = widths[0];
    for (j = 0; j < width; ++j) {
        g_a[j] = g_h[j] - g_h[j] * act[j] * act[j];
        gz[j] += g_a[j];
    }
    for (i = 0; i < 2 * nx; ++i) {
        double acc = 0.0;
        const double *wi = params + i * width;
        double *gwi = g_params + i * width;
        for (j = 0; j < width; ++j) {
            gwi[j] += xf[i] * g_a[j];
            acc += g_a[j] * wi[j];
        }
        g_xf[i] = acc;
    }
    /* through the FMU: f enters the first layer and the output */
    for (i = 0; i < nx; ++i) g_fmu[i] += g_xf[nx + i];
    for (j = 0; j < nx + nu; ++j) {
        double acc = 0.0;
        for (i = 0; i < nx; ++i) acc += g_fmu[i] * jac[i * (nx + nu) + j];
        if (j < nx)
            gx[j] = g_xf[j] + acc;
        else
            gu[j - nx] += acc;
    }
}

/* Reverse sweep of a recorded rollout (hf_neural_forward_record): grad_states (n_steps + 1, B, nx) = dL/dstates
   -> g_x0 (B, nx), and added into the zero-initialised g_u_grid (n_steps + 1, B, nu), g_u_half (n_steps, B, nu),
   g_z_grid (n_steps + 1, B, H_0), g_z_half (n_steps, B, H_0) and g_params (layout of params). A clamped step
   passes no gradient to the end stop's position and rate. n_act <= 64.
   work: 10 * nx + 2 * max(H) doubles. */
int hf_neural_backward(size_t nx, size_t nu, size_t n_steps, size_t batch, double h, int rk4, size_t n_act,
                       const size_t *widths, const double *params, const double *xf_rec, const double *jac_rec,
                       const double *act_rec, const unsigned char *clamped, long long i_pos, long long i_rate,
                       const double *grad_states, double *g_x0, double *g_u_grid, double *g_u_half,
                       double *g_z_grid, double *g_z_half, double *g_params, double *work) {
    const size_t h0 = widths[0], stages = rk4 ? 4 : 1;
    size_t width_sum = 0, l, r, i, s;
    long long k;
    double *lam = work, *gy = lam + nx, *gx[4], *stage_work = gy + 5 * nx;
    if (n_act > 64) return HF_ERR_NO_MEMORY;
    for (l = 0; l < n_act; ++l) width_sum += widths[l];
    for (s = 0; s < 4; ++s) gx[s] = gy + (s + 1) * nx;
    for (r = 0; r < batch; ++r) {
        for (i = 0; i < nx; ++i) lam[i] = grad_states[(n_steps * batch + r) * nx + i];
        for (k = (long long)n_steps - 1; k >= 0; --k) {
            const size_t kk = (size_t)k;
            double *gus[4], *gzs[4];
            if (clamped[kk * batch + r] && i_pos >= 0) lam[i_pos] = 0.0, lam[i_rate] = 0.0;
            gus[0] = g_u_grid + (kk * batch + r) * nu;
            gzs[0] = g_z_grid + (kk * batch + r) * h0;
            if (rk4) {
                gus[1] = gus[2] = g_u_half + (kk * batch + r) * nu;
                gzs[1] = gzs[2] = g_z_half + (kk * batch + r) * h0;
                gus[3] = gus[0] + batch * nu;
                gzs[3] = gzs[0] + batch * h0;
            }
            for (s = stages; s-- > 0;) {
                const size_t j = (kk * stages + s) * batch + r;
                if (!rk4) {
                    for (i = 0; i < nx; ++i) gy[i] = lam[i] * h;
                } else if (s == 3) {
                    for (i = 0; i < nx; ++i) gy[i] = lam[i] * (h / 6.0);
                } else if (s == 0) {
                    for (i = 0; i < nx; ++i) gy[i] = lam[i] * (h / 6.0) + 0.5 * h * gx[1][i];
                } else {
                    const double c = s == 2 ? h : 0.5 * h;
                    for (i = 0; i < nx; ++i) gy[i] = lam[i] * (h / 3.0) + c * gx[s + 1][i];
                }
                hf_neural_stage_backward(nx, nu, xf_rec + j * 2 * nx, jac_rec + j * nx * (nx + nu),
                                         act_rec + j * width_sum, n_act, widths, params, g_params, gy, gx[s],
                                         gus[s], gzs[s], stage_work);
            }
            for (i = 0; i < nx; ++i) {
                if (rk4)
                    lam[i] += ((gx[0][i] + gx[1][i]) + (gx[2][i] + gx[3][i]));
                else
                    lam[i] += gx[0][i];
                lam[i] += grad_states[(kk * batch + r) * nx + i];
            }
        }
        for (i = 0; i < nx; ++i) g_x0[r * nx + i] = lam[i];
    }
    return 0;
}
