/*
 * Oscillator: a Van der Pol oscillator with two states and no inputs.
 *
 *   dx/dt = v
 *   dv/dt = mu omega_0 (1 - x^2) v - omega_0^2 x
 *
 * x (1), v (1/s); parameters mu (1, >= 0, strength of the nonlinear damping) and omega_0
 * (1/s, > 0, natural angular frequency); output energy = (v^2 + omega_0^2 x^2) / 2 (1/s2).
 * It provides no directional derivatives, so importers fall back to finite differences.
 */
#include <math.h>
#include <stdio.h>

#include "fmu_core.h"

/* Storage indices of the Real variables; equal to their value references. */
enum { X, V, DER_X, DER_V, MU, OMEGA_0, ENERGY, N_REALS };
enum { N_INTEGERS = 0, N_STATES = 2, N_EVENT_INDICATORS = 0 };

_Static_assert(MODEL_N_REALS == N_REALS, "Real variables of modelDescription.xml and Oscillator.c differ");
_Static_assert(MODEL_N_INTEGERS == N_INTEGERS, "Integer variables of modelDescription.xml and Oscillator.c differ");
_Static_assert(MODEL_N_STATES == N_STATES, "states of modelDescription.xml and Oscillator.c differ");
_Static_assert(MODEL_N_EVENT_INDICATORS == N_EVENT_INDICATORS, "numberOfEventIndicators differs");
_Static_assert(MODEL_PROVIDES_DIRECTIONAL_DERIVATIVE == 0, "Oscillator provides no directional derivatives");

/* clang-format off */
const VarInfo model_variables[] = {
    {X,       "x",       VAR_REAL, VAR_STATE,      X,       2.0},
    {V,       "v",       VAR_REAL, VAR_STATE,      V,       0.0},
    {DER_X,   "der(x)",  VAR_REAL, VAR_DERIVATIVE, DER_X,   0.0},
    {DER_V,   "der(v)",  VAR_REAL, VAR_DERIVATIVE, DER_V,   0.0},
    {MU,      "mu",      VAR_REAL, VAR_PARAMETER,  MU,      1.0},
    {OMEGA_0, "omega_0", VAR_REAL, VAR_PARAMETER,  OMEGA_0, 1.0},
    {ENERGY,  "energy",  VAR_REAL, VAR_OUTPUT,     ENERGY,  0.0},
};
/* clang-format on */
const size_t model_n_variables = sizeof model_variables / sizeof model_variables[0];

const size_t model_state_index[N_STATES] = {X, V};
const size_t model_derivative_index[N_STATES] = {DER_X, DER_V};
const double model_state_nominal[N_STATES] = {1.0, 1.0};

int model_check_value(const VarInfo *variable, double value, char *message, size_t size) {
    const char *expected = NULL;
    if (variable->index == MU && !(value >= 0.0)) expected = "the damping strength must be >= 0";
    if (variable->index == OMEGA_0 && !(value > 0.0)) expected = "the natural angular frequency must be > 0 1/s";
    if (expected == NULL) return 0;
    snprintf(message, size, "parameter \"%s\" = %g is invalid: %s", variable->name, value, expected);
    return 1;
}

int model_check_parameter_relations(const ModelData *data, char *message, size_t size) {
    (void)data;
    (void)message;
    (void)size; /* no relations between the parameters */
    return 0;
}

void model_calculate(ModelData *data) {
    double *r = data->real;
    double w = r[OMEGA_0];
    r[DER_X] = r[V];
    r[DER_V] = r[MU] * w * (1.0 - r[X] * r[X]) * r[V] - w * w * r[X];
    r[ENERGY] = 0.5 * (r[V] * r[V] + w * w * r[X] * r[X]);
}

void model_event_indicators(const ModelData *data, double indicators[]) {
    (void)data;
    (void)indicators; /* no event indicators */
}

int model_event_update(ModelInstance *instance) {
    (void)instance; /* no discrete states */
    return 0;
}

int model_step_event_needed(const ModelData *data) {
    (void)data;
    return 0;
}
