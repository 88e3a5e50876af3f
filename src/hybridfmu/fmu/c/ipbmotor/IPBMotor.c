/*
 * IPBMotor: permanent-magnet synchronous motor of an integrated power brake, in the rotor
 * (d, q) frame, with the rotor's end stops as state events.
 *
 * States x = [i_d, i_q, theta, omega] (A, A, rad, rad/s); inputs u = [d_a, d_b, d_c, u_dc,
 * tau_load] (duty 0..1, V, N m). With theta_e = p theta:
 *   phase voltages     v_k = u_dc (d_k - (d_a + d_b + d_c)/3)
 *   Clarke             v_alpha = (2/3)(v_a - v_b/2 - v_c/2),  v_beta = (v_b - v_c)/sqrt(3)
 *   Park               v_d = v_alpha cos(theta_e) + v_beta sin(theta_e)
 *                      v_q = -v_alpha sin(theta_e) + v_beta cos(theta_e)
 *   electrics          L_d di_d/dt = v_d - R i_d + p omega L_q i_q
 *                      L_q di_q/dt = v_q - R i_q - p omega (L_d i_d + psi)
 *   torque             tau_e = 1.5 p (psi i_q + (L_d - L_q) i_d i_q)
 *   mechanics (free)   dtheta/dt = omega,  J domega/dt = tau_e - b omega - tau_load
 * Outputs: tau_e, phase currents i_a, i_b, i_c (inverse Park, inverse amplitude-invariant
 * Clarke), v_d, v_q, and the discrete stop_mode.
 *
 * End stops theta_min <= theta <= theta_max. The discrete state stop_mode is 0 (free), +1
 * (held at theta_max) or -1 (held at theta_min). Held at a stop, theta is clamped and
 * dtheta/dt = domega/dt = omega = 0. With the drive torque tau_drive = tau_e - tau_load
 * (the net torque at omega = 0):
 *   free -> +1  when theta reaches theta_max: omega > 0 is set to 0 (inelastic stop), theta
 *               clamped; the rotor is held if tau_drive > 0 (pushing into the stop), else it
 *               stays free (it moves away again).
 *   +1 -> free  when tau_drive <= 0 (the net torque points away from the stop).
 * and mirrored at theta_min. Event indicators:
 *   z0 = theta - theta_min   (free or at theta_max; 1 while held at theta_min)
 *   z1 = theta_max - theta   (free or at theta_min; 1 while held at theta_max)
 *   z2 = tau_drive at theta_max, -tau_drive at theta_min, 1 when free
 * so a crossing from positive to negative always means "an event is due". After a release
 * (or a stop reached while the torque already points away) the rotor sits exactly at the
 * stop, so z0 or z1 is 0 and turns positive as the rotor leaves: importers that follow FMI's
 * domains z > 0 / z <= 0 see one more event there, at which nothing changes.
 * fmi2CompletedIntegratorStep asks for event mode whenever the values contradict the mode
 * (beyond a stop while free; torque pointing away, or states set off the stop, while held),
 * a safety net for importers that miss a crossing.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "fmu_core.h"

/* Storage indices of the Real variables; equal to their value references. */
enum {
    I_D, I_Q, THETA, OMEGA,                         /* states */
    DER_I_D, DER_I_Q, DER_THETA, DER_OMEGA,         /* state derivatives */
    D_A, D_B, D_C, U_DC, TAU_LOAD,                  /* inputs */
    P, R, L_D, L_Q, PSI, J, B, THETA_MIN, THETA_MAX, /* parameters */
    TAU_E, I_A, I_B, I_C, V_D, V_Q,                 /* outputs */
    N_REALS
};
/* Storage indices of the Integer variables (value reference = N_REALS + index). */
enum { STOP_MODE, N_INTEGERS };
enum { N_STATES = 4, N_INPUTS = 5, N_EVENT_INDICATORS = 3 };
enum { STOP_AT_MIN = -1, STOP_FREE = 0, STOP_AT_MAX = 1 };

_Static_assert(MODEL_N_REALS == N_REALS, "Real variables of modelDescription.xml and IPBMotor.c differ");
_Static_assert(MODEL_N_INTEGERS == N_INTEGERS, "Integer variables of modelDescription.xml and IPBMotor.c differ");
_Static_assert(MODEL_N_STATES == N_STATES, "states of modelDescription.xml and IPBMotor.c differ");
_Static_assert(MODEL_N_EVENT_INDICATORS == N_EVENT_INDICATORS, "numberOfEventIndicators differs");
_Static_assert(MODEL_PROVIDES_DIRECTIONAL_DERIVATIVE == 1, "IPBMotor provides directional derivatives");

#define SQRT3 1.7320508075688772935

/* clang-format off */
const VarInfo model_variables[] = {
    {I_D,       "i_d",        VAR_REAL, VAR_STATE,      I_D,       0.0},
    {I_Q,       "i_q",        VAR_REAL, VAR_STATE,      I_Q,       0.0},
    {THETA,     "theta",      VAR_REAL, VAR_STATE,      THETA,     0.1},
    {OMEGA,     "omega",      VAR_REAL, VAR_STATE,      OMEGA,     0.0},
    {DER_I_D,   "der(i_d)",   VAR_REAL, VAR_DERIVATIVE, DER_I_D,   0.0},
    {DER_I_Q,   "der(i_q)",   VAR_REAL, VAR_DERIVATIVE, DER_I_Q,   0.0},
    {DER_THETA, "der(theta)", VAR_REAL, VAR_DERIVATIVE, DER_THETA, 0.0},
    {DER_OMEGA, "der(omega)", VAR_REAL, VAR_DERIVATIVE, DER_OMEGA, 0.0},
    {D_A,       "d_a",        VAR_REAL, VAR_INPUT,      D_A,       0.5},
    {D_B,       "d_b",        VAR_REAL, VAR_INPUT,      D_B,       0.5},
    {D_C,       "d_c",        VAR_REAL, VAR_INPUT,      D_C,       0.5},
    {U_DC,      "u_dc",       VAR_REAL, VAR_INPUT,      U_DC,      12.0},
    {TAU_LOAD,  "tau_load",   VAR_REAL, VAR_INPUT,      TAU_LOAD,  0.0},
    {P,         "p",          VAR_REAL, VAR_PARAMETER,  P,         4.0},
    {R,         "R",          VAR_REAL, VAR_PARAMETER,  R,         0.03},
    {L_D,       "L_d",        VAR_REAL, VAR_PARAMETER,  L_D,       60e-6},
    {L_Q,       "L_q",        VAR_REAL, VAR_PARAMETER,  L_Q,       60e-6},
    {PSI,       "psi",        VAR_REAL, VAR_PARAMETER,  PSI,       6e-3},
    {J,         "J",          VAR_REAL, VAR_PARAMETER,  J,         2e-4},
    {B,         "b",          VAR_REAL, VAR_PARAMETER,  B,         2e-5},
    {THETA_MIN, "theta_min",  VAR_REAL, VAR_PARAMETER,  THETA_MIN, 0.0},
    {THETA_MAX, "theta_max",  VAR_REAL, VAR_PARAMETER,  THETA_MAX, 60.0},
    {TAU_E,     "tau_e",      VAR_REAL, VAR_OUTPUT,     TAU_E,     0.0},
    {I_A,       "i_a",        VAR_REAL, VAR_OUTPUT,     I_A,       0.0},
    {I_B,       "i_b",        VAR_REAL, VAR_OUTPUT,     I_B,       0.0},
    {I_C,       "i_c",        VAR_REAL, VAR_OUTPUT,     I_C,       0.0},
    {V_D,       "v_d",        VAR_REAL, VAR_OUTPUT,     V_D,       0.0},
    {V_Q,       "v_q",        VAR_REAL, VAR_OUTPUT,     V_Q,       0.0},
    {N_REALS + STOP_MODE, "stop_mode", VAR_INTEGER, VAR_OUTPUT, STOP_MODE, 0.0},
};
/* clang-format on */
const size_t model_n_variables = sizeof model_variables / sizeof model_variables[0];

const size_t model_state_index[N_STATES] = {I_D, I_Q, THETA, OMEGA};
const size_t model_derivative_index[N_STATES] = {DER_I_D, DER_I_Q, DER_THETA, DER_OMEGA};
/* typical magnitudes: currents ~10 A, angle ~1 rad, speed ~100 rad/s */
const double model_state_nominal[N_STATES] = {10.0, 10.0, 1.0, 100.0};

/* ------------------------------------------------------------------------ checks */

int model_check_value(const VarInfo *variable, double value, char *message, size_t size) {
    const char *expected = NULL;
    switch (variable->index) {
    case P:
        if (!(value >= 1.0 && value == floor(value))) expected = "the number of pole pairs must be a whole number >= 1";
        break;
    case R: if (!(value >= 0.0)) expected = "the stator resistance must be >= 0 ohm"; break;
    case L_D: if (!(value > 0.0)) expected = "the d-axis inductance must be > 0 H"; break;
    case L_Q: if (!(value > 0.0)) expected = "the q-axis inductance must be > 0 H"; break;
    case PSI: if (!(value >= 0.0)) expected = "the permanent-magnet flux linkage must be >= 0 Wb"; break;
    case J: if (!(value > 0.0)) expected = "the rotor inertia must be > 0 kg m2"; break;
    case B: if (!(value >= 0.0)) expected = "the viscous friction coefficient must be >= 0 N m s/rad"; break;
    default: break;
    }
    if (expected == NULL) return 0;
    snprintf(message, size, "parameter \"%s\" = %g is invalid: %s", variable->name, value, expected);
    return 1;
}

int model_check_parameter_relations(const ModelData *data, char *message, size_t size) {
    if (!(data->real[THETA_MIN] < data->real[THETA_MAX])) {
        snprintf(message, size,
                 "parameters \"theta_min\" = %g and \"theta_max\" = %g are invalid: theta_min must be < theta_max",
                 data->real[THETA_MIN], data->real[THETA_MAX]);
        return 1;
    }
    return 0;
}

/* ------------------------------------------------------------------------ equations */

/* Quantities shared by the equations and their partial derivatives. */
typedef struct {
    double cos_e, sin_e;        /* of theta_e = p theta */
    double v_alpha, v_beta;     /* V */
    double v_d, v_q;            /* V */
    double dvalpha_du[N_INPUTS]; /* d v_alpha / d u, u = [d_a, d_b, d_c, u_dc, tau_load] */
    double dvbeta_du[N_INPUTS];
    double tau_e;               /* N m */
} Terms;

static void terms(const double *r, Terms *t) {
    double theta_e = r[P] * r[THETA];
    t->cos_e = cos(theta_e);
    t->sin_e = sin(theta_e);
    double mean_duty = (r[D_A] + r[D_B] + r[D_C]) / 3.0;
    double v_a = r[U_DC] * (r[D_A] - mean_duty);
    double v_b = r[U_DC] * (r[D_B] - mean_duty);
    double v_c = r[U_DC] * (r[D_C] - mean_duty);
    t->v_alpha = (2.0 / 3.0) * (v_a - 0.5 * v_b - 0.5 * v_c);
    t->v_beta = (v_b - v_c) / SQRT3;
    t->v_d = t->v_alpha * t->cos_e + t->v_beta * t->sin_e;
    t->v_q = -t->v_alpha * t->sin_e + t->v_beta * t->cos_e;
    /* the common mode cancels: v_alpha = (2/3) u_dc (d_a - (d_b + d_c)/2), v_beta = u_dc (d_b - d_c)/sqrt(3) */
    double u_dc = r[U_DC];
    t->dvalpha_du[0] = (2.0 / 3.0) * u_dc;
    t->dvalpha_du[1] = -(1.0 / 3.0) * u_dc;
    t->dvalpha_du[2] = -(1.0 / 3.0) * u_dc;
    t->dvalpha_du[3] = (2.0 / 3.0) * (r[D_A] - 0.5 * (r[D_B] + r[D_C]));
    t->dvalpha_du[4] = 0.0;
    t->dvbeta_du[0] = 0.0;
    t->dvbeta_du[1] = u_dc / SQRT3;
    t->dvbeta_du[2] = -u_dc / SQRT3;
    t->dvbeta_du[3] = (r[D_B] - r[D_C]) / SQRT3;
    t->dvbeta_du[4] = 0.0;
    t->tau_e = 1.5 * r[P] * (r[PSI] * r[I_Q] + (r[L_D] - r[L_Q]) * r[I_D] * r[I_Q]);
}

void model_calculate(ModelData *data) {
    double *r = data->real;
    Terms t;
    terms(r, &t);
    double p = r[P];
    r[DER_I_D] = (t.v_d - r[R] * r[I_D] + p * r[OMEGA] * r[L_Q] * r[I_Q]) / r[L_D];
    r[DER_I_Q] = (t.v_q - r[R] * r[I_Q] - p * r[OMEGA] * (r[L_D] * r[I_D] + r[PSI])) / r[L_Q];
    if (data->integer[STOP_MODE] == STOP_FREE) {
        r[DER_THETA] = r[OMEGA];
        r[DER_OMEGA] = (t.tau_e - r[B] * r[OMEGA] - r[TAU_LOAD]) / r[J];
    } else {
        r[DER_THETA] = 0.0;
        r[DER_OMEGA] = 0.0;
    }
    double i_alpha = r[I_D] * t.cos_e - r[I_Q] * t.sin_e;
    double i_beta = r[I_D] * t.sin_e + r[I_Q] * t.cos_e;
    r[TAU_E] = t.tau_e;
    r[I_A] = i_alpha;
    r[I_B] = -0.5 * i_alpha + 0.5 * SQRT3 * i_beta;
    r[I_C] = -0.5 * i_alpha - 0.5 * SQRT3 * i_beta;
    r[V_D] = t.v_d;
    r[V_Q] = t.v_q;
}

/* Net torque on the rotor at rest: electromagnetic minus load torque (N m). */
static double drive_torque(const double *r) {
    return 1.5 * r[P] * (r[PSI] * r[I_Q] + (r[L_D] - r[L_Q]) * r[I_D] * r[I_Q]) - r[TAU_LOAD];
}

/* ------------------------------------------------------------------------ events */

void model_event_indicators(const ModelData *data, double z[]) {
    const double *r = data->real;
    int mode = data->integer[STOP_MODE];
    double tau_drive = drive_torque(r);
    z[0] = mode == STOP_AT_MIN ? 1.0 : r[THETA] - r[THETA_MIN];
    z[1] = mode == STOP_AT_MAX ? 1.0 : r[THETA_MAX] - r[THETA];
    z[2] = mode == STOP_AT_MAX ? tau_drive : mode == STOP_AT_MIN ? -tau_drive : 1.0;
}

int model_event_update(ModelInstance *instance) {
    ModelData *data = &instance->state.data;
    double *r = data->real;
    int *mode = &data->integer[STOP_MODE];
    double time_s = instance->state.time_s;
    double tau_drive = drive_torque(r);
    int changed = 0;

    /* held at a stop: follow a changed stop parameter or changed states; release when the
       net torque points away from the stop */
    if (*mode == STOP_AT_MAX) {
        if (r[THETA] < r[THETA_MAX]) {
            *mode = STOP_FREE; /* the stop moved away (theta_max raised) or the angle was set below it */
            fmu_log(instance, fmi2OK, LOG_EVENTS, "t = %.9g s: theta %g below theta_max %g, no longer held", time_s,
                    r[THETA], r[THETA_MAX]);
        } else {
            if (r[THETA] != r[THETA_MAX] || r[OMEGA] != 0.0) {
                r[THETA] = r[THETA_MAX];
                r[OMEGA] = 0.0;
                changed = 1;
            }
            if (tau_drive <= 0.0) {
                *mode = STOP_FREE;
                fmu_log(instance, fmi2OK, LOG_EVENTS, "t = %.9g s: released from theta_max (net torque %g N m)",
                        time_s, tau_drive);
            }
        }
    } else if (*mode == STOP_AT_MIN) {
        if (r[THETA] > r[THETA_MIN]) {
            *mode = STOP_FREE;
            fmu_log(instance, fmi2OK, LOG_EVENTS, "t = %.9g s: theta %g above theta_min %g, no longer held", time_s,
                    r[THETA], r[THETA_MIN]);
        } else {
            if (r[THETA] != r[THETA_MIN] || r[OMEGA] != 0.0) {
                r[THETA] = r[THETA_MIN];
                r[OMEGA] = 0.0;
                changed = 1;
            }
            if (tau_drive >= 0.0) {
                *mode = STOP_FREE;
                fmu_log(instance, fmi2OK, LOG_EVENTS, "t = %.9g s: released from theta_min (net torque %g N m)",
                        time_s, tau_drive);
            }
        }
    }

    /* free: reaching (or being beyond) a stop clamps the angle and stops motion into it */
    if (*mode == STOP_FREE) {
        if (r[THETA] >= r[THETA_MAX]) {
            if (r[THETA] != r[THETA_MAX]) {
                r[THETA] = r[THETA_MAX];
                changed = 1;
            }
            if (r[OMEGA] > 0.0) {
                fmu_log(instance, fmi2OK, LOG_EVENTS, "t = %.9g s: theta_max reached at omega = %g rad/s", time_s,
                        r[OMEGA]);
                r[OMEGA] = 0.0;
                changed = 1;
            }
            if (r[OMEGA] == 0.0 && tau_drive > 0.0) {
                *mode = STOP_AT_MAX;
                fmu_log(instance, fmi2OK, LOG_EVENTS, "t = %.9g s: held at theta_max (net torque %g N m)", time_s,
                        tau_drive);
            }
        } else if (r[THETA] <= r[THETA_MIN]) {
            if (r[THETA] != r[THETA_MIN]) {
                r[THETA] = r[THETA_MIN];
                changed = 1;
            }
            if (r[OMEGA] < 0.0) {
                fmu_log(instance, fmi2OK, LOG_EVENTS, "t = %.9g s: theta_min reached at omega = %g rad/s", time_s,
                        r[OMEGA]);
                r[OMEGA] = 0.0;
                changed = 1;
            }
            if (r[OMEGA] == 0.0 && tau_drive < 0.0) {
                *mode = STOP_AT_MIN;
                fmu_log(instance, fmi2OK, LOG_EVENTS, "t = %.9g s: held at theta_min (net torque %g N m)", time_s,
                        tau_drive);
            }
        }
    }
    return changed;
}

int model_step_event_needed(const ModelData *data) {
    const double *r = data->real;
    double tau_drive = drive_torque(r);
    switch (data->integer[STOP_MODE]) {
    /* held: the torque points away, or the states were set off the stop */
    case STOP_AT_MAX: return tau_drive < 0.0 || r[THETA] != r[THETA_MAX] || r[OMEGA] != 0.0;
    case STOP_AT_MIN: return tau_drive > 0.0 || r[THETA] != r[THETA_MIN] || r[OMEGA] != 0.0;
    default: return r[THETA] > r[THETA_MAX] || r[THETA] < r[THETA_MIN];
    }
}

/* ------------------------------------------------------------------------ directional derivatives */

/* Rows: the four state derivatives then the six Real outputs; columns: states then inputs. */
enum { N_ROWS = 10, N_COLS = N_STATES + N_INPUTS };

static int row_of(size_t index) {
    if (index >= DER_I_D && index <= DER_OMEGA) return (int)(index - DER_I_D);
    if (index >= TAU_E && index <= V_Q) return (int)(4 + index - TAU_E);
    return -1;
}

static int column_of(size_t index) {
    if (index <= OMEGA) return (int)index;
    if (index >= D_A && index <= TAU_LOAD) return (int)(N_STATES + index - D_A);
    return -1;
}

/* Partial derivatives of the state derivatives and the outputs w.r.t. states and inputs. */
static void jacobian(const ModelData *data, double jac[N_ROWS][N_COLS]) {
    const double *r = data->real;
    Terms t;
    terms(r, &t);
    memset(jac, 0, sizeof(double) * N_ROWS * N_COLS);
    double p = r[P], i_d = r[I_D], i_q = r[I_Q], omega = r[OMEGA];
    double c = t.cos_e, s = t.sin_e;

    double dvd_du[N_INPUTS], dvq_du[N_INPUTS];
    for (int k = 0; k < N_INPUTS; ++k) {
        dvd_du[k] = c * t.dvalpha_du[k] + s * t.dvbeta_du[k];
        dvq_du[k] = -s * t.dvalpha_du[k] + c * t.dvbeta_du[k];
    }
    double dtau_did = 1.5 * p * (r[L_D] - r[L_Q]) * i_q;
    double dtau_diq = 1.5 * p * (r[PSI] + (r[L_D] - r[L_Q]) * i_d);

    /* der(i_d) = (v_d - R i_d + p omega L_q i_q) / L_d, with d v_d / d theta = p v_q */
    jac[0][0] = -r[R] / r[L_D];
    jac[0][1] = p * omega * r[L_Q] / r[L_D];
    jac[0][2] = p * t.v_q / r[L_D];
    jac[0][3] = p * r[L_Q] * i_q / r[L_D];
    /* der(i_q) = (v_q - R i_q - p omega (L_d i_d + psi)) / L_q, with d v_q / d theta = -p v_d */
    jac[1][0] = -p * omega * r[L_D] / r[L_Q];
    jac[1][1] = -r[R] / r[L_Q];
    jac[1][2] = -p * t.v_d / r[L_Q];
    jac[1][3] = -p * (r[L_D] * i_d + r[PSI]) / r[L_Q];
    for (int k = 0; k < N_INPUTS; ++k) {
        jac[0][N_STATES + k] = dvd_du[k] / r[L_D];
        jac[1][N_STATES + k] = dvq_du[k] / r[L_Q];
    }
    if (data->integer[STOP_MODE] == STOP_FREE) {
        /* der(theta) = omega; der(omega) = (tau_e - b omega - tau_load) / J */
        jac[2][3] = 1.0;
        jac[3][0] = dtau_did / r[J];
        jac[3][1] = dtau_diq / r[J];
        jac[3][3] = -r[B] / r[J];
        jac[3][N_STATES + 4] = -1.0 / r[J];
    } /* held at a stop: der(theta) = der(omega) = 0 */

    /* tau_e */
    jac[4][0] = dtau_did;
    jac[4][1] = dtau_diq;
    /* i_alpha = i_d c - i_q s, i_beta = i_d s + i_q c; d/d theta: (-p i_beta, p i_alpha) */
    double i_alpha = i_d * c - i_q * s, i_beta = i_d * s + i_q * c;
    double dalpha[3] = {c, -s, -p * i_beta}; /* w.r.t. i_d, i_q, theta */
    double dbeta[3] = {s, c, p * i_alpha};
    for (int k = 0; k < 3; ++k) {
        jac[5][k] = dalpha[k];                                    /* i_a = i_alpha */
        jac[6][k] = -0.5 * dalpha[k] + 0.5 * SQRT3 * dbeta[k];    /* i_b */
        jac[7][k] = -0.5 * dalpha[k] - 0.5 * SQRT3 * dbeta[k];    /* i_c */
    }
    /* v_d, v_q */
    jac[8][2] = p * t.v_q;
    jac[9][2] = -p * t.v_d;
    for (int k = 0; k < N_INPUTS; ++k) {
        jac[8][N_STATES + k] = dvd_du[k];
        jac[9][N_STATES + k] = dvq_du[k];
    }
}

int model_directional_derivative(const ModelData *data, const VarInfo *const unknowns[], size_t n_unknowns,
                                 const VarInfo *const knowns[], size_t n_knowns, const double dv_known[],
                                 double dv_unknown[], char *message, size_t size) {
    for (size_t i = 0; i < n_unknowns; ++i) {
        if (row_of(unknowns[i]->index) < 0) {
            snprintf(message, size,
                     "unknown \"%s\" is not supported: unknowns must be state derivatives or Real outputs",
                     unknowns[i]->name);
            return 1;
        }
    }
    for (size_t j = 0; j < n_knowns; ++j) {
        if (column_of(knowns[j]->index) < 0) {
            snprintf(message, size, "known \"%s\" is not supported: knowns must be continuous states or inputs",
                     knowns[j]->name);
            return 1;
        }
    }
    double jac[N_ROWS][N_COLS];
    jacobian(data, jac);
    for (size_t i = 0; i < n_unknowns; ++i) {
        int row = row_of(unknowns[i]->index);
        double sum = 0.0;
        for (size_t j = 0; j < n_knowns; ++j) sum += jac[row][column_of(knowns[j]->index)] * dv_known[j];
        dv_unknown[i] = sum;
    }
    return 0;
}
