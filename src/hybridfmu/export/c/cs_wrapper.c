/*
 * An exported model of the workflow as an FMI 2.0 Co-Simulation FMU.
 *
 * The case's Model-Exchange FMU travels unchanged inside this FMU (resources/<inner>.fmu, and the same archive
 * extracted beside it in resources/<inner>/ so that its binary can be loaded). This wrapper loads that binary,
 * instantiates it in Model-Exchange mode with the calibrated parameters, and integrates the exported model on
 * the case's sample grid with the loops of the workflow's own C engine (hybridfmu/fmu/shim.c, included below):
 *
 *   - EXPORT_EVENTS 0, a neural FMU (or a hybrid) in its fused form: one hf_neural_rollout step per sample,
 *     with the learned input delays read from an input history by linear interpolation at the positions the
 *     workflow uses, and the first layer's input term z = u W_u + b computed here;
 *   - EXPORT_EVENTS 1, the FMU (+ diagnosed effects) as the workflow's open loop simulates it: RK4 per sample
 *     with the inputs held, the FMU's state, time, input and step events handled (hf_settle, hf_run_grid), the
 *     FMU initialised at the first sample with the start states and inputs, as hybridfmu.fmu.simulate does;
 *   - an effect program (effects.c) added to the FMU's derivatives where the model has one (a hybrid's
 *     physical layer), and the diagnosed changes of the logged inputs as stages applied to each new sample
 *     (time shifts, lags, dead zones, saturations, gains, offsets: hybridfmu/export/input_stages.py), before the
 *     delays read them.
 *
 * A step k of the model reads inputs up to sample k + EXPORT_LOOKAHEAD (the input stages and the delays
 * interpolate towards later samples, RK4's last stage reads sample k + 1). A co-simulation master gives the FMU no future input, so the
 * FMU integrates step k once it has received sample k + EXPORT_LOOKAHEAD: its outputs lag the model by
 * EXPORT_LOOKAHEAD samples (the constant output_delay_s). Samples before the first are the first sample (the
 * workflow holds a record's first input before its start).
 *
 * Everything specific to one model (sizes, value references, weights, delays, parameters) comes from the
 * generated header export_model.h; this file knows no model.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#include "shim.c"

#include "export_model.h"

/* ---------------------------------------------------------------- value references of this FMU
   0 .. NU-1: the inputs; NU .. NU+NX-1: the states (outputs); NU+NX .. NU+2NX-1: the states' start values
   (parameters); NU+2NX: output_delay_s (constant); then the effect coefficients (tunable parameters). */
#define VR_INPUT0 0u
#define VR_STATE0 ((unsigned)EXPORT_NU)
#define VR_START0 ((unsigned)(EXPORT_NU + EXPORT_NX))
#define VR_OUTPUT_DELAY ((unsigned)(EXPORT_NU + 2 * EXPORT_NX))
#define VR_COEFF0 ((unsigned)(EXPORT_NU + 2 * EXPORT_NX + 1))
#define VR_END ((unsigned)(EXPORT_NU + 2 * EXPORT_NX + 1 + EXPORT_N_COEFFICIENTS))

/* The input history keeps the samples a step can read: EXPORT_LOOKBACK before the step and EXPORT_LOOKAHEAD
   after it; each input stage's ring the samples the next stage reads. */
#define RING (EXPORT_LOOKAHEAD + EXPORT_LOOKBACK + 4)
#define STAGE_RING (EXPORT_STAGE_REACH + 4)
#define N_SEQUENCES (EXPORT_NU + EXPORT_N_STAGES > 0 ? EXPORT_NU + EXPORT_N_STAGES : 1)

typedef enum { MODE_INSTANTIATED, MODE_INITIALIZATION, MODE_STEPPING, MODE_TERMINATED, MODE_ERROR } exp_mode;

typedef struct {
    fmi2Component (*instantiate)(fmi2String, fmi2Type, fmi2String, fmi2String, const fmi2CallbackFunctions *,
                                 fmi2Boolean, fmi2Boolean);
    void (*free_instance)(fmi2Component);
    fmi2Status (*setup_experiment)(fmi2Component, fmi2Boolean, fmi2Real, fmi2Real, fmi2Boolean, fmi2Real);
    fmi2Status (*enter_initialization_mode)(fmi2Component);
    fmi2Status (*exit_initialization_mode)(fmi2Component);
    fmi2Status (*terminate)(fmi2Component);
    fmi2Status (*reset)(fmi2Component);
    fmi2Status (*set_real)(fmi2Component, const fmi2ValueReference *, size_t, const fmi2Real *);
    fmi2Status (*get_real)(fmi2Component, const fmi2ValueReference *, size_t, fmi2Real *);
    fmi2Status (*new_discrete_states)(fmi2Component, fmi2EventInfo *);
    fmi2Status (*enter_continuous_time_mode)(fmi2Component);
    fmi2Status (*enter_event_mode)(fmi2Component);
    fmi2Status (*get_continuous_states)(fmi2Component, fmi2Real *, size_t);
    fmi2Status (*set_time)(fmi2Component, fmi2Real);
    fmi2Status (*set_continuous_states)(fmi2Component, const fmi2Real *, size_t);
    fmi2Status (*get_derivatives)(fmi2Component, fmi2Real *, size_t);
    fmi2Status (*get_event_indicators)(fmi2Component, fmi2Real *, size_t);
    fmi2Status (*completed_integrator_step)(fmi2Component, fmi2Boolean, fmi2Boolean *, fmi2Boolean *);
    fmi2Status (*get_directional_derivative)(fmi2Component, const fmi2ValueReference *, size_t,
                                             const fmi2ValueReference *, size_t, const fmi2Real *, fmi2Real *);
} exp_inner_api;

typedef struct {
    fmi2CallbackFunctions callbacks;
    char *instance_name;
    int logging_on;
    void *library;
    exp_inner_api api;
    fmi2Component inner;
    hf_model model;
    exp_mode mode;
    double time_s;
    double start_time_s; /* setupExperiment's start time */
    int terminated;      /* the embedded FMU asked to end the run */
    double u_now[EXPORT_NU > 0 ? EXPORT_NU : 1];
    double x[EXPORT_NX];
    double x_start[EXPORT_NX];
    double coefficients[EXPORT_N_COEFFICIENTS > 0 ? EXPORT_N_COEFFICIENTS : 1];
    double effect_reals[EXPORT_N_EFFECT_REALS > 0 ? EXPORT_N_EFFECT_REALS : 1];
    double first_sample[EXPORT_NU > 0 ? EXPORT_NU : 1];
    double history[RING][EXPORT_NU > 0 ? EXPORT_NU : 1]; /* the inputs as the model sees them (after the stages) */
    /* the input stages: sequence c < NU is input c as logged, sequence NU + s the output of stage s */
    double sequence[N_SEQUENCES][STAGE_RING];
    double sequence_first[N_SEQUENCES];
    double lag_state[EXPORT_N_STAGES > 0 ? EXPORT_N_STAGES : 1][2]; /* actuator_lag: the filter's output, input */
    long long n_raw;     /* logged samples received */
    long long n_samples; /* samples of the inputs as the model sees them */
    long long n_steps;   /* model steps done: x is the state at sample n_steps */
    /* one step's buffers (hf_neural_rollout with batch 1) */
    double u_grid[2][EXPORT_NU > 0 ? EXPORT_NU : 1];
    double u_half[EXPORT_NU > 0 ? EXPORT_NU : 1];
    double z_grid[2][EXPORT_WIDTH0];
    double z_half[EXPORT_WIDTH0];
    double states[2][EXPORT_NX];
    double work[6 * EXPORT_NX + EXPORT_NX + EXPORT_WIDTH_SUM];
    double effect_out[EXPORT_NX];
    double effect_work[EXPORT_NU + EXPORT_NX + 1];
#if EXPORT_EVENTS
    /* the open loop with events (hf_run_grid on one sample interval at a time) */
    hf_events events;
    double z_prev[EXPORT_INNER_NZ > 0 ? EXPORT_INNER_NZ : 1];
    double grid_time[2];
    double grid_u[2][EXPORT_NU > 0 ? EXPORT_NU : 1];
    double grid_x[2][EXPORT_NX];
    double event_work[16 * EXPORT_NX + 6 * (EXPORT_INNER_NZ > 0 ? EXPORT_INNER_NZ : 1) + 1];
    double log_time[EXPORT_LOG_CAPACITY];
    int log_kind[EXPORT_LOG_CAPACITY];
    int log_reinit[EXPORT_LOG_CAPACITY];
    unsigned char log_crossed[EXPORT_LOG_CAPACITY * (EXPORT_INNER_NZ > 0 ? EXPORT_INNER_NZ : 1)];
    double outcome_x[EXPORT_NX];
#endif
} exp_instance;

static void exp_log(exp_instance *c, fmi2Status status, const char *category, const char *format, ...) {
    char message[1024];
    va_list args;
    if (!c || !c->callbacks.logger) return;
    if (status == fmi2OK && !c->logging_on) return;
    va_start(args, format);
    vsnprintf(message, sizeof message, format, args);
    va_end(args);
    c->callbacks.logger(c->callbacks.componentEnvironment, c->instance_name, status, category, "%s", message);
}

static fmi2Status exp_fail(exp_instance *c, const char *format, const char *detail) {
    exp_log(c, fmi2Error, "logStatusError", format, detail);
    return fmi2Error;
}

/* The file system path of a file:// URI (file:///a/b or file:/a/b); NULL if it is not one. */
static char *exp_uri_path(const char *uri) {
    const char *path;
    char *out;
    size_t i, j, n;
    if (!uri) return NULL;
    if (strncmp(uri, "file://", 7) == 0) {
        path = uri + 7;
        if (strncmp(path, "localhost/", 10) == 0) path += 9;
    } else if (strncmp(uri, "file:", 5) == 0) {
        path = uri + 5;
    } else {
        return NULL;
    }
    n = strlen(path);
    out = (char *)malloc(n + 1);
    if (!out) return NULL;
    for (i = 0, j = 0; i < n; ++i) { /* percent-decoding */
        if (path[i] == '%' && i + 2 < n + 1 && path[i + 1] && path[i + 2]) {
            char hex[3] = {path[i + 1], path[i + 2], 0};
            out[j++] = (char)strtol(hex, NULL, 16);
            i += 2;
        } else {
            out[j++] = path[i];
        }
    }
    while (j > 1 && out[j - 1] == '/') --j;
    out[j] = 0;
    return out;
}

static int exp_load_inner(exp_instance *c, const char *resources) {
    char path[4096];
    snprintf(path, sizeof path, "%s/%s/binaries/linux64/%s.so", resources, EXPORT_INNER_DIR,
             EXPORT_INNER_IDENTIFIER);
    /* RTLD_DEEPBIND: the inner FMU's calls to its own fmi2 functions stay within it, whatever the host loaded */
    c->library = dlopen(path, RTLD_NOW | RTLD_LOCAL | RTLD_DEEPBIND);
    if (!c->library) {
        exp_log(c, fmi2Error, "logStatusError", "cannot load the embedded FMU's binary %s: %s", path, dlerror());
        return 0;
    }
#define EXP_SYMBOL(field, name)                                                                         \
    do {                                                                                                \
        *(void **)(&c->api.field) = dlsym(c->library, name);                                            \
        if (!c->api.field) {                                                                            \
            exp_log(c, fmi2Error, "logStatusError", "the embedded FMU's binary %s lacks %s", path, name); \
            return 0;                                                                                   \
        }                                                                                               \
    } while (0)
    EXP_SYMBOL(instantiate, "fmi2Instantiate");
    EXP_SYMBOL(free_instance, "fmi2FreeInstance");
    EXP_SYMBOL(setup_experiment, "fmi2SetupExperiment");
    EXP_SYMBOL(enter_initialization_mode, "fmi2EnterInitializationMode");
    EXP_SYMBOL(exit_initialization_mode, "fmi2ExitInitializationMode");
    EXP_SYMBOL(terminate, "fmi2Terminate");
    EXP_SYMBOL(reset, "fmi2Reset");
    EXP_SYMBOL(set_real, "fmi2SetReal");
    EXP_SYMBOL(get_real, "fmi2GetReal");
    EXP_SYMBOL(new_discrete_states, "fmi2NewDiscreteStates");
    EXP_SYMBOL(enter_continuous_time_mode, "fmi2EnterContinuousTimeMode");
    EXP_SYMBOL(enter_event_mode, "fmi2EnterEventMode");
    EXP_SYMBOL(get_continuous_states, "fmi2GetContinuousStates");
    EXP_SYMBOL(set_time, "fmi2SetTime");
    EXP_SYMBOL(set_continuous_states, "fmi2SetContinuousStates");
    EXP_SYMBOL(get_derivatives, "fmi2GetDerivatives");
    EXP_SYMBOL(get_event_indicators, "fmi2GetEventIndicators");
    EXP_SYMBOL(completed_integrator_step, "fmi2CompletedIntegratorStep");
#undef EXP_SYMBOL
    *(void **)(&c->api.get_directional_derivative) = dlsym(c->library, "fmi2GetDirectionalDerivative");
    return 1;
}

/* The shim's record of the inner FMU (hybridfmu/fmu/shim.c), as the workflow's bridge fills it. */
static void exp_setup_model(exp_instance *c) {
    hf_model *m = &c->model;
    memset(m, 0, sizeof *m);
    m->component = c->inner;
    m->set_time = (hf_set_time_fn)c->api.set_time;
    m->set_states = (hf_set_states_fn)c->api.set_continuous_states;
    m->set_real = (hf_set_real_fn)c->api.set_real;
    m->get_real = (hf_get_real_fn)c->api.get_real;
    m->get_derivatives = (hf_get_vector_fn)c->api.get_derivatives;
    m->get_event_indicators = (hf_get_vector_fn)c->api.get_event_indicators;
    m->get_directional_derivative = (hf_dir_der_fn)c->api.get_directional_derivative;
    m->completed_integrator_step = (hf_completed_fn)c->api.completed_integrator_step;
    m->enter_event_mode = (hf_mode_fn)c->api.enter_event_mode;
    m->new_discrete_states = (hf_new_discrete_states_fn)c->api.new_discrete_states;
    m->enter_continuous_time_mode = (hf_mode_fn)c->api.enter_continuous_time_mode;
    m->get_continuous_states = (hf_get_vector_fn)c->api.get_continuous_states;
    m->nx = EXPORT_NX;
    m->nu = EXPORT_NU;
    m->nz = EXPORT_INNER_NZ;
    m->vr_u = export_inner_vr_u;
    m->vr_x = export_inner_vr_x;
    m->vr_dx = export_inner_vr_dx;
#if EXPORT_EVENTS
    memset(&c->events, 0, sizeof c->events);
    c->events.tolerance_s = EXPORT_EVENT_TOLERANCE_S;
    c->events.max_events = EXPORT_MAX_EVENTS;
    c->events.max_iterations = EXPORT_MAX_EVENT_ITERATIONS;
    c->events.next_time_event = INFINITY;
    c->events.capacity = EXPORT_LOG_CAPACITY;
    c->events.log_time = c->log_time;
    c->events.log_kind = c->log_kind;
    c->events.log_reinit = c->log_reinit;
    c->events.log_crossed = c->log_crossed;
    c->events.outcome_x = c->outcome_x;
#endif
#if EXPORT_N_EFFECT_CODE > 0
    m->effect_code = export_effect_code;
    m->effect_n_code = EXPORT_N_EFFECT_CODE;
    m->effect_reals = c->effect_reals;
    m->effect_out = c->effect_out;
    m->effect_work = c->effect_work;
    m->effect_sets_inputs = EXPORT_EFFECT_SETS_INPUTS;
#endif
}

/* The inner FMU instantiated in Model-Exchange mode with the calibrated parameters set. */
static int exp_instantiate_inner(exp_instance *c, const char *resources) {
    char uri[4200];
    snprintf(uri, sizeof uri, "file://%s/%s/resources", resources, EXPORT_INNER_DIR);
    c->inner = c->api.instantiate(c->instance_name, fmi2ModelExchange, EXPORT_INNER_GUID, uri, &c->callbacks,
                                  fmi2False, c->logging_on ? fmi2True : fmi2False);
    if (!c->inner) {
        exp_log(c, fmi2Error, "logStatusError", "fmi2Instantiate of the embedded FMU %s failed",
                EXPORT_INNER_IDENTIFIER);
        return 0;
    }
    return 1;
}

static fmi2Status exp_set_inner_parameters(exp_instance *c) {
#if EXPORT_N_PARAMETERS > 0
    if (c->api.set_real(c->inner, export_parameter_vr, EXPORT_N_PARAMETERS, export_parameter_value) > fmi2Warning)
        return exp_fail(c, "%s: setting the calibrated parameters failed", EXPORT_INNER_IDENTIFIER);
#endif
    return fmi2OK;
}

/* setupExperiment at start_s, initialisation, the event iteration and continuous-time mode, as the workflow's
   bridge initialises an FMU; *next_time_event: the FMU's next time event then (INFINITY if none). */
static fmi2Status exp_initialise_inner(exp_instance *c, double start_s, double *next_time_event) {
    fmi2EventInfo info;
    int i;
    if (c->api.setup_experiment(c->inner, fmi2False, 0.0, start_s, fmi2False, 0.0) > fmi2Warning ||
        c->api.enter_initialization_mode(c->inner) > fmi2Warning ||
        c->api.exit_initialization_mode(c->inner) > fmi2Warning)
        return exp_fail(c, "%s: initialisation of the embedded FMU failed", EXPORT_INNER_IDENTIFIER);
    for (i = 0; i < EXPORT_MAX_EVENT_ITERATIONS; ++i) {
        memset(&info, 0, sizeof info);
        if (c->api.new_discrete_states(c->inner, &info) > fmi2Warning)
            return exp_fail(c, "%s: fmi2NewDiscreteStates failed", EXPORT_INNER_IDENTIFIER);
        if (info.terminateSimulation)
            return exp_fail(c, "%s: the embedded FMU asked to terminate during initialisation",
                            EXPORT_INNER_IDENTIFIER);
        if (!info.newDiscreteStatesNeeded) break;
    }
    if (i == EXPORT_MAX_EVENT_ITERATIONS)
        return exp_fail(c, "%s: the event iteration of the initialisation did not settle", EXPORT_INNER_IDENTIFIER);
    *next_time_event = info.nextEventTimeDefined ? info.nextEventTime : INFINITY;
    if (c->api.enter_continuous_time_mode(c->inner) > fmi2Warning)
        return exp_fail(c, "%s: fmi2EnterContinuousTimeMode failed", EXPORT_INNER_IDENTIFIER);
    return fmi2OK;
}

static void exp_defaults(exp_instance *c) {
    memcpy(c->x_start, export_x_start, sizeof c->x_start);
#if EXPORT_NU > 0
    memcpy(c->u_now, export_u_start, sizeof c->u_now);
#endif
#if EXPORT_N_COEFFICIENTS > 0
    memcpy(c->coefficients, export_coefficient_start, sizeof c->coefficients);
#endif
    c->n_raw = 0;
    c->n_samples = 0;
    c->n_steps = 0;
    c->time_s = 0.0;
    c->terminated = 0;
}

/* The effect program's reals with the current coefficients written at their places. */
static void exp_effect_reals(exp_instance *c) {
#if EXPORT_N_EFFECT_REALS > 0
    size_t i;
    memcpy(c->effect_reals, export_effect_reals, sizeof c->effect_reals);
#if EXPORT_N_COEFFICIENTS > 0
    for (i = 0; i < EXPORT_N_COEFFICIENTS; ++i) c->effect_reals[export_coefficient_index[i]] = c->coefficients[i];
#else
    (void)i;
#endif
#else
    (void)c;
#endif
}

/* ---------------------------------------------------------------- the model's steps */

/* Sample j of the input history (j < 0: the first sample). */
static const double *exp_sample(const exp_instance *c, long long j) {
    if (j <= 0) return c->first_sample;
    return c->history[j % RING];
}

/* u(t_k + offset h + dt) for every input: lerp of samples (k + first[i], k + first[i] + 1) with weight frac[i],
   computed as torch.lerp computes it. */
static void exp_delayed(const exp_instance *c, long long k, const int *first, const double *frac, double *u) {
    size_t i;
    for (i = 0; i < EXPORT_NU; ++i) {
        const double lower = exp_sample(c, k + first[i])[i], upper = exp_sample(c, k + first[i] + 1)[i];
        const double w = frac[i];
        u[i] = fabs(w) < 0.5 ? lower + w * (upper - lower) : upper - (upper - lower) * (1.0 - w);
    }
}

/* z = b_first + u W_u (first layer's input term), W_u (NU, H0) row-major. */
static void exp_input_term(const double *u, double *z) {
    size_t i, j;
    for (j = 0; j < EXPORT_WIDTH0; ++j) z[j] = export_b_first[j];
    for (i = 0; i < EXPORT_NU; ++i)
        for (j = 0; j < EXPORT_WIDTH0; ++j) z[j] += u[i] * export_w_u[i * EXPORT_WIDTH0 + j];
}

#if EXPORT_EVENTS
/* The embedded FMU initialised as hybridfmu.fmu.simulate initialises it at the start of an open loop: the start
   states (those it accepts as start values) and the first inputs set, setupExperiment at the start time,
   initialisation, the event iteration, continuous-time mode; then the event iteration at the start state. */
static fmi2Status exp_events_start(exp_instance *c, const double *u) {
    size_t i;
    int status;
    for (i = 0; i < EXPORT_NX; ++i)
        if (export_state_start_settable[i] &&
            c->api.set_real(c->inner, &export_inner_vr_x[i], 1, &c->x_start[i]) > fmi2Warning)
            return exp_fail(c, "%s: setting a start state failed", EXPORT_INNER_IDENTIFIER);
    if (EXPORT_NU && c->api.set_real(c->inner, export_inner_vr_u, EXPORT_NU, u) > fmi2Warning)
        return exp_fail(c, "%s: setting the first inputs failed", EXPORT_INNER_IDENTIFIER);
    if (exp_initialise_inner(c, c->start_time_s, &c->events.next_time_event) != fmi2OK) return fmi2Error;
    c->events.count = 0;
    status = hf_settle(&c->model, &c->events, c->start_time_s, c->x, u, c->z_prev);
    c->events.count = 0;
    if (status == HF_STOP) return exp_fail(c, "%s", "the embedded FMU ended the run at its start");
    if (status) return exp_fail(c, "%s", "the event iteration at the start failed");
    return fmi2OK;
}

/* Step k of the FMU (+ effects) with the inputs u held: the state at sample k -> the state at sample k + 1. */
static fmi2Status exp_events_step(exp_instance *c, long long k, const double *u) {
    long long k_out = 0;
    int status;
    if (k == 0 && exp_events_start(c, u) != fmi2OK) return fmi2Error;
    c->grid_time[0] = c->start_time_s + (double)k / EXPORT_RATE_HZ;
    c->grid_time[1] = c->start_time_s + (double)(k + 1) / EXPORT_RATE_HZ;
    memcpy(c->grid_u[0], u, sizeof c->grid_u[0]);
    memcpy(c->grid_u[1], u, sizeof c->grid_u[1]);
    memcpy(c->grid_x[0], c->x, sizeof c->x);
    c->events.count = 0;
    status = hf_run_grid(&c->model, &c->events, 2, c->grid_time, &c->grid_u[0][0], 0, &c->grid_x[0][0], c->z_prev,
                         c->event_work, &k_out);
    c->events.count = 0;
    if (status) {
        char detail[200];
        snprintf(detail, sizeof detail, "step %lld (t = %.9g s): the embedded FMU's function %d failed with status %d",
                 k, c->grid_time[0], c->model.failed_function, status);
        return exp_fail(c, "%s", detail);
    }
    if (c->events.outcome == HF_OUT_TERMINATE) {
        exp_log(c, fmi2Discard, "logStatusDiscard", "the embedded FMU asked to terminate at t = %.9g s",
                c->events.outcome_time);
        memcpy(c->x, c->outcome_x, sizeof c->x);
        c->terminated = 1;
        return fmi2Discard;
    }
    if (c->events.outcome != HF_OUT_DONE) {
        char detail[200];
        snprintf(detail, sizeof detail, "step %lld: the event handling stopped (outcome %d at t = %.9g s: too many "
                 "events, a time event in the past, non-finite states or an event iteration that does not settle)",
                 k, c->events.outcome, c->events.outcome_time);
        return exp_fail(c, "%s", detail);
    }
    memcpy(c->x, c->grid_x[1], sizeof c->x);
    c->n_steps = k + 1;
    return fmi2OK;
}
#endif

/* Step k of the model: x (the state at sample k) -> the state at sample k + 1. */
static fmi2Status exp_step(exp_instance *c, long long k) {
    size_t done = 0;
    int status;
#if EXPORT_EVENTS
    return exp_events_step(c, k, exp_sample(c, k));
#endif
    exp_delayed(c, k, export_grid_first, export_grid_frac, c->u_grid[0]);
    exp_delayed(c, k + 1, export_grid_first, export_grid_frac, c->u_grid[1]);
    exp_input_term(c->u_grid[0], c->z_grid[0]);
    exp_input_term(c->u_grid[1], c->z_grid[1]);
    if (EXPORT_RK4) {
        exp_delayed(c, k, export_half_first, export_half_frac, c->u_half);
        exp_input_term(c->u_half, c->z_half);
    }
    status = hf_neural_rollout(&c->model, 1, 1, EXPORT_H_S, EXPORT_RK4, c->x, &c->u_grid[0][0], c->u_half,
                               &c->z_grid[0][0], c->z_half, EXPORT_N_LAYERS, export_widths, export_params,
                               EXPORT_I_POS, EXPORT_I_RATE, EXPORT_POS_LOWER, EXPORT_POS_UPPER, &c->states[0][0],
                               c->work, &done, NULL);
    if (status) {
        char detail[256];
        snprintf(detail, sizeof detail, "step %lld (t = %.9g s): the embedded FMU's function %d failed with status %d",
                 k, k * EXPORT_H_S, c->model.failed_function, status);
        return exp_fail(c, "%s", detail);
    }
    if (done < 1) {
        char detail[160];
        snprintf(detail, sizeof detail, "step %lld (t = %.9g s): a state became non-finite", k, k * EXPORT_H_S);
        return exp_fail(c, "%s", detail);
    }
    memcpy(c->x, c->states[1], sizeof c->x);
    c->n_steps = k + 1;
    return fmi2OK;
}

/* Sample i of sequence q (i < 0: its first sample). */
static double exp_sequence_value(const exp_instance *c, int q, long long i) {
    if (i <= 0) return c->sequence_first[q];
    return c->sequence[q][i % STAGE_RING];
}

static void exp_sequence_store(exp_instance *c, int q, long long i, double value) {
    if (i == 0) c->sequence_first[q] = value;
    c->sequence[q][i % STAGE_RING] = value;
}

/* v at the fractional index i + offset, as hybridfmu.diagnosis.effects.shift_samples interpolates it: lower =
   max(floor(i + offset), 0), upper = lower + 1, weight = the index's fraction. */
static double exp_shifted(const exp_instance *c, int q, long long i, double offset) {
    const double index = (double)i + offset, base = floor(index), frac = index - base;
    const long long lower = base < 0.0 ? 0 : (long long)base;
    return (1.0 - frac) * exp_sequence_value(c, q, lower) + frac * exp_sequence_value(c, q, lower + 1);
}

/* Output i of input stage s, reading sequence q (its input). */
static double exp_stage_value(exp_instance *c, int s, int q, long long i) {
    const double *r = export_stage_reals[s];
    const double v = exp_sequence_value(c, q, i);
    switch (export_stage_kind[s]) {
    case 1: /* shift */
        return exp_shifted(c, q, i, r[0]);
    case 2: /* shift_mix */
        return v + r[0] * (exp_shifted(c, q, i, r[1]) - v);
    case 3: { /* actuator_lag: z[0] = v[0], z[i] = (1 - a) v[i-1] + a z[i-1] (scipy's lfilter with zi = v[0]) */
        double z;
        if (i == 0) z = v;
        else z = r[3] * c->lag_state[s][1] - (-r[1]) * c->lag_state[s][0];
        c->lag_state[s][0] = z;
        c->lag_state[s][1] = v;
        return v + r[0] * ((v + (z - v) * r[2] * r[3]) - v);
    }
    case 4: /* lag */
        return v + r[0] * ((exp_sequence_value(c, q, i + 1) - v) / r[1]);
    case 5: /* deadzone */
        return v - r[0] * fmin(fmax(v, -r[1]), r[1]);
    case 6: /* saturation_above */
        return v + r[0] * -fmax(v - r[1], 0.0);
    case 7: /* saturation_below */
        return v + r[0] * fmax(r[1] - v, 0.0);
    case 8: /* gain */
        return (1.0 + r[0]) * v;
    case 9: /* offset */
        return v + r[0];
    case 10: /* linear: the mean over the step of the line through the samples */
        return 0.5 * (v + exp_sequence_value(c, q, i + 1));
    default:
        return NAN;
    }
}

/* Step k of the model, once the inputs as the model sees them reach sample k + EXPORT_LOOKAHEAD. */
static fmi2Status exp_take_model_sample(exp_instance *c, const double *u) {
    const long long n = c->n_samples;
    if (n == 0) memcpy(c->first_sample, u, sizeof c->first_sample);
    memcpy(c->history[n % RING], u, sizeof c->history[0]);
    c->n_samples = n + 1;
    if (n - EXPORT_LOOKAHEAD >= 0) return exp_step(c, n - EXPORT_LOOKAHEAD);
    return fmi2OK;
}

/* Receive the current inputs as the next logged sample: run it through the input stages (each stage computes
   its sample as soon as the samples it reads ahead have arrived) and pass the inputs as the model sees them on,
   EXPORT_INPUT_LOOKAHEAD samples later. */
static fmi2Status exp_take_sample(exp_instance *c) {
    const long long n = c->n_raw;
    double u[EXPORT_NU > 0 ? EXPORT_NU : 1];
    size_t column;
    int s;
    c->n_raw = n + 1;
    for (column = 0; column < EXPORT_NU; ++column) {
        long long index = n;
        int q = (int)column;
        exp_sequence_store(c, q, n, c->u_now[column]);
        for (s = 0; s < EXPORT_N_STAGES; ++s) {
            if (export_stage_column[s] != (int)column) continue;
            index -= export_stage_lookahead[s];
            if (index < 0) break;
            exp_sequence_store(c, EXPORT_NU + s, index, exp_stage_value(c, s, q, index));
            q = EXPORT_NU + s;
        }
    }
    if (n - EXPORT_INPUT_LOOKAHEAD < 0) return fmi2OK;
    for (column = 0; column < EXPORT_NU; ++column)
        u[column] = exp_sequence_value(c, export_final_sequence[column], n - EXPORT_INPUT_LOOKAHEAD);
    return exp_take_model_sample(c, u);
}

/* ---------------------------------------------------------------- FMI 2.0 Co-Simulation API */

FMI2_Export const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
FMI2_Export const char *fmi2GetVersion(void) { return fmi2Version; }

FMI2_Export fmi2Status fmi2SetDebugLogging(fmi2Component component, fmi2Boolean loggingOn, size_t nCategories,
                                           const fmi2String categories[]) {
    exp_instance *c = (exp_instance *)component;
    (void)nCategories;
    (void)categories;
    if (!c) return fmi2Error;
    c->logging_on = loggingOn ? 1 : 0;
    return fmi2OK;
}

FMI2_Export fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                                          fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                                          fmi2Boolean visible, fmi2Boolean loggingOn) {
    exp_instance *c;
    char *resources;
    (void)visible;
    if (!functions || !functions->allocateMemory || !functions->freeMemory) return NULL;
    c = (exp_instance *)calloc(1, sizeof(exp_instance));
    if (!c) return NULL;
    c->callbacks = *functions;
    c->logging_on = loggingOn ? 1 : 0;
    c->instance_name = strdup(instanceName ? instanceName : EXPORT_MODEL_IDENTIFIER);
    c->mode = MODE_ERROR;
    if (fmuType != fmi2CoSimulation) {
        exp_log(c, fmi2Error, "logStatusError", "%s is a Co-Simulation FMU; fmi2Instantiate asked for another type",
                EXPORT_MODEL_IDENTIFIER);
        goto fail;
    }
    if (!fmuGUID || strcmp(fmuGUID, EXPORT_GUID) != 0) {
        exp_log(c, fmi2Error, "logStatusError", "GUID %s does not match this FMU's %s", fmuGUID ? fmuGUID : "(null)",
                EXPORT_GUID);
        goto fail;
    }
    resources = exp_uri_path(fmuResourceLocation);
    if (!resources) {
        exp_log(c, fmi2Error, "logStatusError", "fmuResourceLocation %s is not a file URI",
                fmuResourceLocation ? fmuResourceLocation : "(null)");
        goto fail;
    }
    if (!exp_load_inner(c, resources) || !exp_instantiate_inner(c, resources)) {
        free(resources);
        goto fail;
    }
    free(resources);
    if (exp_set_inner_parameters(c) != fmi2OK) goto fail;
    exp_setup_model(c);
    exp_defaults(c);
    c->mode = MODE_INSTANTIATED;
    return (fmi2Component)c;
fail:
    if (c->inner) c->api.free_instance(c->inner);
    if (c->library) dlclose(c->library);
    free(c->instance_name);
    free(c);
    return NULL;
}

FMI2_Export void fmi2FreeInstance(fmi2Component component) {
    exp_instance *c = (exp_instance *)component;
    if (!c) return;
    if (c->inner) c->api.free_instance(c->inner);
    if (c->library) dlclose(c->library);
    free(c->instance_name);
    free(c);
}

FMI2_Export fmi2Status fmi2SetupExperiment(fmi2Component component, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                                           fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    exp_instance *c = (exp_instance *)component;
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (!c || c->mode != MODE_INSTANTIATED) return fmi2Error;
    c->time_s = startTime;
    c->start_time_s = startTime;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2EnterInitializationMode(fmi2Component component) {
    exp_instance *c = (exp_instance *)component;
    if (!c || c->mode != MODE_INSTANTIATED) return fmi2Error;
    c->mode = MODE_INITIALIZATION;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2ExitInitializationMode(fmi2Component component) {
    exp_instance *c = (exp_instance *)component;
    double next_time_event; /* unused by the neural rollout, which handles no events */
    if (!c || c->mode != MODE_INITIALIZATION) return fmi2Error;
    if (!EXPORT_EVENTS && exp_initialise_inner(c, 0.0, &next_time_event) != fmi2OK) { /* events: first sample */
        c->mode = MODE_ERROR;
        return fmi2Error;
    }
    exp_effect_reals(c);
    memcpy(c->x, c->x_start, sizeof c->x);
    c->n_raw = 0;
    c->n_samples = 0;
    c->n_steps = 0;
    c->mode = MODE_STEPPING;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2Terminate(fmi2Component component) {
    exp_instance *c = (exp_instance *)component;
    if (!c) return fmi2Error;
    if (c->mode == MODE_STEPPING) c->api.terminate(c->inner);
    c->mode = MODE_TERMINATED;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2Reset(fmi2Component component) {
    exp_instance *c = (exp_instance *)component;
    if (!c) return fmi2Error;
    if (c->api.reset(c->inner) > fmi2Warning) return exp_fail(c, "%s: fmi2Reset of the embedded FMU failed",
                                                              EXPORT_INNER_IDENTIFIER);
    if (exp_set_inner_parameters(c) != fmi2OK) return fmi2Error;
    exp_defaults(c);
    c->mode = MODE_INSTANTIATED;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                                   fmi2Real value[]) {
    exp_instance *c = (exp_instance *)component;
    size_t i;
    if (!c || (nvr && (!vr || !value))) return fmi2Error;
    for (i = 0; i < nvr; ++i) {
        const unsigned r = vr[i];
        if (r < VR_STATE0) value[i] = c->u_now[r - VR_INPUT0];
        else if (r < VR_START0) value[i] = c->mode == MODE_STEPPING || c->mode == MODE_TERMINATED
                                               ? c->x[r - VR_STATE0] : c->x_start[r - VR_STATE0];
        else if (r < VR_OUTPUT_DELAY) value[i] = c->x_start[r - VR_START0];
        else if (r == VR_OUTPUT_DELAY) value[i] = (EXPORT_LOOKAHEAD + EXPORT_INPUT_LOOKAHEAD) * EXPORT_H_S;
        else if (r < VR_END) value[i] = c->coefficients[r - VR_COEFF0];
        else {
            exp_log(c, fmi2Error, "logStatusError", "fmi2GetReal: unknown value reference %u", r);
            return fmi2Error;
        }
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                                   const fmi2Real value[]) {
    exp_instance *c = (exp_instance *)component;
    size_t i;
    if (!c || (nvr && (!vr || !value))) return fmi2Error;
    for (i = 0; i < nvr; ++i) {
        const unsigned r = vr[i];
        if (r < VR_STATE0) {
            c->u_now[r - VR_INPUT0] = value[i];
        } else if (r >= VR_START0 && r < VR_OUTPUT_DELAY) {
            if (c->mode != MODE_INSTANTIATED && c->mode != MODE_INITIALIZATION) {
                exp_log(c, fmi2Error, "logStatusError", "fmi2SetReal: the start value (value reference %u) is "
                        "fixed after initialisation", r);
                return fmi2Error;
            }
            c->x_start[r - VR_START0] = value[i];
        } else if (r >= VR_COEFF0 && r < VR_END) {
            c->coefficients[r - VR_COEFF0] = value[i];
            if (c->mode == MODE_STEPPING) exp_effect_reals(c);
        } else {
            exp_log(c, fmi2Error, "logStatusError", "fmi2SetReal: value reference %u cannot be set", r);
            return fmi2Error;
        }
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    (void)vr;
    (void)value;
    return c && nvr == 0 ? fmi2OK : fmi2Error;
}
FMI2_Export fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    (void)vr;
    (void)value;
    return c && nvr == 0 ? fmi2OK : fmi2Error;
}
FMI2_Export fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    (void)vr;
    (void)value;
    return c && nvr == 0 ? fmi2OK : fmi2Error;
}
FMI2_Export fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                      const fmi2Integer value[]) {
    (void)vr;
    (void)value;
    return c && nvr == 0 ? fmi2OK : fmi2Error;
}
FMI2_Export fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                      const fmi2Boolean value[]) {
    (void)vr;
    (void)value;
    return c && nvr == 0 ? fmi2OK : fmi2Error;
}
FMI2_Export fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                     const fmi2String value[]) {
    (void)vr;
    (void)value;
    return c && nvr == 0 ? fmi2OK : fmi2Error;
}

/* canGetAndSetFMUstate and canSerializeFMUstate are false */
FMI2_Export fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    (void)c;
    (void)state;
    return fmi2Error;
}
FMI2_Export fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    (void)c;
    (void)state;
    return fmi2Error;
}
FMI2_Export fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    (void)c;
    (void)state;
    return fmi2Error;
}
FMI2_Export fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size) {
    (void)c;
    (void)state;
    (void)size;
    return fmi2Error;
}
FMI2_Export fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[], size_t size) {
    (void)c;
    (void)state;
    (void)bytes;
    (void)size;
    return fmi2Error;
}
FMI2_Export fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size,
                                               fmi2FMUstate *state) {
    (void)c;
    (void)bytes;
    (void)size;
    (void)state;
    return fmi2Error;
}
/* providesDirectionalDerivative is false */
FMI2_Export fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown[],
                                                    size_t nUnknown, const fmi2ValueReference vKnown[], size_t nKnown,
                                                    const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    (void)c;
    (void)vUnknown;
    (void)nUnknown;
    (void)vKnown;
    (void)nKnown;
    (void)dvKnown;
    (void)dvUnknown;
    return fmi2Error;
}

/* canInterpolateInputs is false and maxOutputDerivativeOrder 0: input derivatives are ignored */
FMI2_Export fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                                   const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return c ? fmi2OK : fmi2Error;
}
FMI2_Export fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                                    const fmi2Integer order[], fmi2Real value[]) {
    (void)vr;
    (void)order;
    (void)value;
    return c && nvr == 0 ? fmi2OK : fmi2Error;
}

FMI2_Export fmi2Status fmi2DoStep(fmi2Component component, fmi2Real currentCommunicationPoint,
                                  fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    exp_instance *c = (exp_instance *)component;
    double samples;
    long long n_sub, j;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!c || c->mode != MODE_STEPPING) return fmi2Error;
    if (c->terminated) return fmi2Discard;
    samples = communicationStepSize / EXPORT_H_S;
    n_sub = llround(samples);
    if (n_sub < 1 || fabs(samples - (double)n_sub) > 1e-6 * (samples > 1.0 ? samples : 1.0)) {
        char detail[200];
        snprintf(detail, sizeof detail, "fmi2DoStep: the communication step %.9g s is not a multiple of the model's "
                 "sample period %.9g s", communicationStepSize, EXPORT_H_S);
        return exp_fail(c, "%s", detail);
    }
    for (j = 0; j < n_sub; ++j) {
        const fmi2Status status = exp_take_sample(c);
        if (status == fmi2Discard) return fmi2Discard;
        if (status != fmi2OK) {
            c->mode = MODE_ERROR;
            return fmi2Error;
        }
    }
    c->time_s = currentCommunicationPoint + communicationStepSize;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2CancelStep(fmi2Component c) {
    (void)c;
    return fmi2Error;
}

FMI2_Export fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)s;
    if (!c || !value) return fmi2Error;
    *value = fmi2OK;
    return fmi2OK;
}
FMI2_Export fmi2Status fmi2GetRealStatus(fmi2Component component, const fmi2StatusKind s, fmi2Real *value) {
    exp_instance *c = (exp_instance *)component;
    if (!c || !value || s != fmi2LastSuccessfulTime) return fmi2Discard;
    *value = c->time_s;
    return fmi2OK;
}
FMI2_Export fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)c;
    (void)s;
    (void)value;
    return fmi2Discard;
}
FMI2_Export fmi2Status fmi2GetBooleanStatus(fmi2Component component, const fmi2StatusKind s, fmi2Boolean *value) {
    exp_instance *c = (exp_instance *)component;
    if (!c || !value || s != fmi2Terminated) return fmi2Discard;
    *value = c->terminated ? fmi2True : fmi2False;
    return fmi2OK;
}
FMI2_Export fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)c;
    (void)s;
    (void)value;
    return fmi2Discard;
}
