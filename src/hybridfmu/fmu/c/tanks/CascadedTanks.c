/*
 * CascadedTanks: two water tanks in cascade (Schoukens, Mattsson, Wigren, Noel 2016), mass
 * balance plus Torricelli's law, without the overflow of the real rig.
 *
 *   dx1/dt = -k1 s(x1) + k4 u          upper tank, filled by the pump
 *   dx2/dt =  k2 s(x1) - k3 s(x2)      lower tank, filled by the upper one
 *   y = x2                             the measured level
 *
 * States x1, x2: tank levels in V of the (uncalibrated) level sensor; input u: pump voltage (V);
 * parameters k1, k2, k3 (V^0.5/s, declared without a unit) and k4 (1/s), all >= 0.
 *
 * s(x) is sqrt(x) guarded for levels at or below zero (an empty tank does not drain): s(x) = 0
 * for x <= 0, sqrt(x) for x >= SQRT_BLEND_V, and in between the quadratic that meets sqrt(x)
 * with value and slope at SQRT_BLEND_V, s(x) = (x / sqrt(d)) (3/2 - x / (2 d)). So s is
 * continuous everywhere, continuously differentiable for x > 0, and its slope stays finite
 * (at most 3 / (2 sqrt(d))) where sqrt(x)'s grows without bound. The directional derivatives are
 * the exact partial derivatives of these equations (one-sided at x = 0: the slope for x > 0).
 */
#include <math.h>
#include <stdio.h>

#include "fmu_core.h"

/* Storage indices of the Real variables; equal to their value references. */
enum {
    X1, X2,           /* states */
    DER_X1, DER_X2,   /* state derivatives */
    U,                /* input */
    K1, K2, K3, K4,   /* parameters */
    Y,                /* output */
    N_REALS
};
enum { N_INTEGERS = 0, N_STATES = 2, N_INPUTS = 1, N_EVENT_INDICATORS = 0 };

_Static_assert(MODEL_N_REALS == N_REALS, "Real variables of modelDescription.xml and CascadedTanks.c differ");
_Static_assert(MODEL_N_INTEGERS == N_INTEGERS, "Integer variables of modelDescription.xml and CascadedTanks.c differ");
_Static_assert(MODEL_N_STATES == N_STATES, "states of modelDescription.xml and CascadedTanks.c differ");
_Static_assert(MODEL_N_EVENT_INDICATORS == N_EVENT_INDICATORS, "numberOfEventIndicators differs");
_Static_assert(MODEL_PROVIDES_DIRECTIONAL_DERIVATIVE == 1, "CascadedTanks provides directional derivatives");

/* Level (V) below which the square root is replaced by its C1 quadratic blend. */
#define SQRT_BLEND_V 1e-3

/* clang-format off */
const VarInfo model_variables[] = {
    {X1,     "x1",      VAR_REAL, VAR_STATE,      X1,     5.0},
    {X2,     "x2",      VAR_REAL, VAR_STATE,      X2,     5.0},
    {DER_X1, "der(x1)", VAR_REAL, VAR_DERIVATIVE, DER_X1, 0.0},
    {DER_X2, "der(x2)", VAR_REAL, VAR_DERIVATIVE, DER_X2, 0.0},
    {U,      "u",       VAR_REAL, VAR_INPUT,      U,      0.0},
    {K1,     "k1",      VAR_REAL, VAR_PARAMETER,  K1,     0.05},
    {K2,     "k2",      VAR_REAL, VAR_PARAMETER,  K2,     0.06},
    {K3,     "k3",      VAR_REAL, VAR_PARAMETER,  K3,     0.09},
    {K4,     "k4",      VAR_REAL, VAR_PARAMETER,  K4,     0.05},
    {Y,      "y",       VAR_REAL, VAR_OUTPUT,     Y,      5.0},
};
/* clang-format on */
const size_t model_n_variables = sizeof model_variables / sizeof model_variables[0];

const size_t model_state_index[N_STATES] = {X1, X2};
const size_t model_derivative_index[N_STATES] = {DER_X1, DER_X2};
/* typical levels: a few volts */
const double model_state_nominal[N_STATES] = {5.0, 5.0};

/* ------------------------------------------------------------------------ checks */

int model_check_value(const VarInfo *variable, double value, char *message, size_t size) {
    const char *expected = NULL;
    switch (variable->index) {
    case K1: if (!(value >= 0.0)) expected = "the upper tank's outflow coefficient must be >= 0 V^0.5/s"; break;
    case K2: if (!(value >= 0.0)) expected = "the lower tank's inflow coefficient must be >= 0 V^0.5/s"; break;
    case K3: if (!(value >= 0.0)) expected = "the lower tank's outflow coefficient must be >= 0 V^0.5/s"; break;
    case K4: if (!(value >= 0.0)) expected = "the pump gain must be >= 0 1/s"; break;
    default: break;
    }
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

/* ------------------------------------------------------------------------ equations */

/* Guarded square root s(x) (file comment), in V^0.5 for x in V. */
static double guarded_sqrt(double x) {
    if (x <= 0.0) return 0.0;
    if (x >= SQRT_BLEND_V) return sqrt(x);
    return x / sqrt(SQRT_BLEND_V) * (1.5 - 0.5 * x / SQRT_BLEND_V);
}

/* ds/dx (V^-0.5); 0 for x <= 0. */
static double guarded_sqrt_slope(double x) {
    if (x <= 0.0) return 0.0;
    if (x >= SQRT_BLEND_V) return 0.5 / sqrt(x);
    return (1.5 - x / SQRT_BLEND_V) / sqrt(SQRT_BLEND_V);
}

void model_calculate(ModelData *data) {
    double *r = data->real;
    double s1 = guarded_sqrt(r[X1]), s2 = guarded_sqrt(r[X2]);
    r[DER_X1] = -r[K1] * s1 + r[K4] * r[U];
    r[DER_X2] = r[K2] * s1 - r[K3] * s2;
    r[Y] = r[X2];
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

/* ------------------------------------------------------------------------ directional derivatives */

/* Rows: der(x1), der(x2), y; columns: x1, x2, u. */
enum { N_ROWS = 3, N_COLS = N_STATES + N_INPUTS };

static int row_of(size_t index) {
    if (index == DER_X1 || index == DER_X2) return (int)(index - DER_X1);
    if (index == Y) return 2;
    return -1;
}

static int column_of(size_t index) {
    if (index == X1 || index == X2) return (int)index;
    if (index == U) return N_STATES;
    return -1;
}

static void jacobian(const ModelData *data, double jac[N_ROWS][N_COLS]) {
    const double *r = data->real;
    double ds1 = guarded_sqrt_slope(r[X1]), ds2 = guarded_sqrt_slope(r[X2]);
    jac[0][0] = -r[K1] * ds1;
    jac[0][1] = 0.0;
    jac[0][2] = r[K4];
    jac[1][0] = r[K2] * ds1;
    jac[1][1] = -r[K3] * ds2;
    jac[1][2] = 0.0;
    jac[2][0] = 0.0;
    jac[2][1] = 1.0;
    jac[2][2] = 0.0;
}

int model_directional_derivative(const ModelData *data, const VarInfo *const unknowns[], size_t n_unknowns,
                                 const VarInfo *const knowns[], size_t n_knowns, const double dv_known[],
                                 double dv_unknown[], char *message, size_t size) {
    for (size_t i = 0; i < n_unknowns; ++i) {
        if (row_of(unknowns[i]->index) < 0) {
            snprintf(message, size,
                     "unknown \"%s\" is not supported: unknowns must be state derivatives or the output y",
                     unknowns[i]->name);
            return 1;
        }
    }
    for (size_t j = 0; j < n_knowns; ++j) {
        if (column_of(knowns[j]->index) < 0) {
            snprintf(message, size, "known \"%s\" is not supported: knowns must be the states x1, x2 or the input u",
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
