/*
 * The diagnosed effects that add a term to the state derivatives, evaluated in C.
 *
 * A diagnosed model (hybridfmu.diagnosis) adds each chosen effect to the FMU in one of three ways: a
 * corrected model parameter, a changed logged input (both applied before a simulation), or a term added
 * to the derivatives at every solver stage. This file evaluates the third kind from a compact program
 * (hybridfmu.fmu.effect_program encodes it), so that an RK4 stage costs no call back into Python. Each
 * term computes the same floating-point operations in the same order as the effect's Python row or batch
 * function in hybridfmu.diagnosis.library (and effects_motor), so both give the same values.
 *
 * Program layout (code: long long, reals: double, both read in order): per term
 *     kind, n_eq, eq[n_eq], n_int, int[n_int], n_real      and its n_real reals.
 * The term's value is added to out[eq] of each of its equations; terms are applied in program order.
 * All indices are validated in Python before a program reaches this file.
 *
 * The hold term (last in a program) holds a velocity x_j at rest by its friction (a Karnopp stick band):
 * within |x_j| < band, with a = f_j + out_j - F(x) the equation's rate without the friction terms F (the
 * listed terms t_1 ..) and F_e = F at x_j = band sign(a) (the friction that opposes a, at the band's edge),
 * the rate becomes -rate x_j where the friction can hold (a (a + F_e) <= 0), else a + F_e; outside the band
 * nothing changes. The term's value is that rate minus f_j + out_j.
 */
#include <math.h>
#include <stddef.h>

#include "effects.h"

/* Term kinds (mirrored in effect_program.py). */
enum {
    HF_TERM_VISCOUS = 1,          /* int: j;        real: c                  -c x_j                          */
    HF_TERM_QUADRATIC = 2,        /* int: j;        real: c                  -c x_j |x_j|                    */
    HF_TERM_POLYNOMIAL = 3,       /* int: j;        real: c_2, c_3, ..       sum_k c_k x_j^k                 */
    HF_TERM_COULOMB = 4,          /* int: j;        real: c, c_s, 1/v_s, eps -(c + c_s e^-(x_j/v_s)^2) tanh(x_j/eps) */
    HF_TERM_SCALED_COULOMB = 5,   /* int: j, k;     real: c, c_a, eps        -(c + c_a s) |u_k| s, s = tanh(x_j/eps) */
    HF_TERM_PERIODIC = 6,         /* int: j;        real: (w, a, b) ..       sum a sin(w x_j) + b cos(w x_j) */
    HF_TERM_SATURATION_ABOVE = 7, /* int: j;        real: c, x_c             c max(x_j - x_c, 0)             */
    HF_TERM_SATURATION_BELOW = 8, /* int: j;        real: c, x_c             c max(x_c - x_j, 0)             */
    HF_TERM_LIMIT_ABOVE = 9,      /* int: i;        real: c, x_c             -c 1[x_i >= x_c] max(f_i, 0)    */
    HF_TERM_LIMIT_BELOW = 10,     /* int: i;        real: c, x_c             c 1[x_i <= x_c] max(-f_i, 0)    */
    HF_TERM_SPILL = 11,           /* int: j;        real: s, x_c             s 1[x_j >= x_c] max(f_j, 0)     */
    HF_TERM_PHASE_DEADTIME = 12,  /* int: d_a, d_b, d_c, i_d, i_q, angle; real: delta, i_0, pole pairs
                                     f(x, u + delta dd) - f(x, u), dd_k = -tanh(i_k / i_0) (motor plugin) */
    HF_TERM_HOLD = 13             /* int: j, friction terms t_1 ..; real: band, rate   (file comment)         */
};

/* pow through a pointer the compiler cannot see through, so that x^2 is libm's pow as in Python (x ** 2),
   never rewritten into x * x */
static double (*volatile hf_effect_pow)(double, double) = pow;

/* Python's max(a, b) for floats: a unless b > a (so NaN and -0.0 in a are kept) */
static double hf_py_max(double a, double b) { return b > a ? b : a; }

/* numpy.maximum(a, b): NaN if either is NaN */
static double hf_np_maximum(double a, double b) {
    if (isnan(a) || isnan(b)) return a + b;
    return a >= b ? a : b;
}

/* The value of a term of one value (any kind but the phase dead time and the hold) at (x, u, f): 0, or
   HF_EFFECT_ERR_PROGRAM for another kind. */
static int hf_term_value(long long kind, const long long *in, long long n_real, const double *c, const double *x,
                         const double *u, const double *f, double *value) {
    double v = 0.0;
    long long m;
    switch (kind) {
    case HF_TERM_VISCOUS:
        v = -c[0] * x[in[0]];
        break;
    case HF_TERM_QUADRATIC:
        v = -c[0] * x[in[0]] * fabs(x[in[0]]);
        break;
    case HF_TERM_POLYNOMIAL:
        for (m = 0; m < n_real; ++m) v += c[m] * hf_effect_pow(x[in[0]], (double)(m + 2));
        break;
    case HF_TERM_COULOMB: {
        const double s = x[in[0]];
        v = -(c[0] + c[1] * exp(-hf_effect_pow(s * c[2], 2.0))) * tanh(s / c[3]);
        break;
    }
    case HF_TERM_SCALED_COULOMB: {
        const double s = tanh(x[in[0]] / c[2]);
        v = -(c[0] + c[1] * s) * fabs(u[in[1]]) * s;
        break;
    }
    case HF_TERM_PERIODIC: {
        const double s = x[in[0]];
        for (m = 0; m + 2 < n_real; m += 3) v += c[m + 1] * sin(c[m] * s) + c[m + 2] * cos(c[m] * s);
        break;
    }
    case HF_TERM_SATURATION_ABOVE:
        v = c[0] * hf_py_max(x[in[0]] - c[1], 0.0);
        break;
    case HF_TERM_SATURATION_BELOW:
        v = c[0] * hf_py_max(c[1] - x[in[0]], 0.0);
        break;
    case HF_TERM_LIMIT_ABOVE:
        v = c[0] * -(x[in[0]] >= c[1] ? hf_np_maximum(f[in[0]], 0.0) : 0.0);
        break;
    case HF_TERM_LIMIT_BELOW:
        v = c[0] * (x[in[0]] <= c[1] ? hf_np_maximum(-f[in[0]], 0.0) : 0.0);
        break;
    case HF_TERM_SPILL:
        v = c[0] * (x[in[0]] >= c[1] ? hf_np_maximum(f[in[0]], 0.0) : 0.0);
        break;
    default:
        return HF_EFFECT_ERR_PROGRAM;
    }
    *value = v;
    return 0;
}

/* The sum, in the order listed, of the terms numbered terms[0 .. n - 1] of the program (terms of one value) at
   (x, u, f). */
static int hf_terms_sum(const long long *code, size_t n_code, const double *reals, const long long *terms,
                        long long n, const double *x, const double *u, const double *f, double *sum) {
    long long k;
    *sum = 0.0;
    for (k = 0; k < n; ++k) {
        size_t p = 0, r = 0;
        long long number = 0;
        double value = 0.0;
        int st;
        while (p < n_code && number < terms[k]) {
            const long long n_eq = code[p + 1], n_int = code[p + 2 + n_eq];
            r += (size_t)code[p + 3 + n_eq + n_int];
            p += 3 + (size_t)n_eq + (size_t)n_int + 1;
            ++number;
        }
        if (p >= n_code) return HF_EFFECT_ERR_PROGRAM;
        {
            const long long n_eq = code[p + 1], n_int = code[p + 2 + n_eq];
            const long long *in = code + p + 3 + n_eq;
            if ((st = hf_term_value(code[p], in, in[n_int], reals + r, x, u, f, &value)) != 0) return st;
        }
        *sum += value;
    }
    return 0;
}

/* The hold term's value (file comment): j = in[0], its friction terms in[1 .. n_int - 1], band c[0], rate c[1];
   before = f_j + out_j, the equation's rate so far. x_edge: nx doubles of work space. */
static int hf_hold_value(const long long *code, size_t n_code, const double *reals, size_t nx,
                         const long long *in, long long n_int, const double *c, const double *x, const double *u,
                         const double *f, double before, double *x_edge, double *value) {
    const long long j = in[0];
    double friction = 0.0, edge = 0.0, a;
    size_t i;
    int st;
    *value = 0.0;
    if (!(fabs(x[j]) < c[0])) return 0;
    if ((st = hf_terms_sum(code, n_code, reals, in + 1, n_int - 1, x, u, f, &friction)) != 0) return st;
    a = before - friction;
    for (i = 0; i < nx; ++i) x_edge[i] = x[i];
    x_edge[j] = a >= 0.0 ? c[0] : -c[0];
    if ((st = hf_terms_sum(code, n_code, reals, in + 1, n_int - 1, x_edge, u, f, &edge)) != 0) return st;
    *value = (a * (a + edge) <= 0.0 ? -c[1] * x[j] : a + edge) - before;
    return 0;
}

int hf_effects_add(const long long *code, size_t n_code, const double *reals, size_t nx, size_t nu,
                   const double *x, const double *u, const double *f, double *out, double *work,
                   hf_effect_eval_fn eval, void *context) {
    size_t p = 0, r = 0, i;
    for (i = 0; i < nx; ++i) out[i] = 0.0;
    while (p < n_code) {
        const long long kind = code[p], n_eq = code[p + 1];
        const long long *eq = code + p + 2;
        const long long n_int = code[p + 2 + n_eq];
        const long long *in = code + p + 3 + n_eq;
        const long long n_real = in[n_int];
        const double *c = reals + r;
        double value = 0.0;
        long long e, m;
        int st;
        p += 3 + (size_t)n_eq + (size_t)n_int + 1;
        r += (size_t)n_real;
        if (kind == HF_TERM_PHASE_DEADTIME) {
            /* phase currents from the rotor-frame currents (amplitude-invariant inverse Park and Clarke) */
            const double i_d = x[in[3]], i_q = x[in[4]], theta_e = c[2] * x[in[5]];
            const double cos_e = cos(theta_e), sin_e = sin(theta_e);
            const double alpha = i_d * cos_e - i_q * sin_e, beta = i_d * sin_e + i_q * cos_e;
            const double half_sqrt3 = 0.5 * sqrt(3.0);
            const double change[3] = {-tanh(alpha / c[1]), -tanh((-0.5 * alpha + half_sqrt3 * beta) / c[1]),
                                      -tanh((-0.5 * alpha - half_sqrt3 * beta) / c[1])};
            double *u_changed = work, *f_changed = work + nu;
            for (i = 0; i < nu; ++i) u_changed[i] = u[i];
            for (m = 0; m < 3; ++m) u_changed[in[m]] += c[0] * change[m];
            if ((st = eval(context, u_changed, f_changed)) != 0) return st;
            for (e = 0; e < n_eq; ++e) out[eq[e]] += f_changed[eq[e]] - f[eq[e]];
            continue; /* one value per equation, added above */
        }
        if (kind == HF_TERM_HOLD)
            st = hf_hold_value(code, n_code, reals, nx, in, n_int, c, x, u, f, f[eq[0]] + out[eq[0]], work, &value);
        else
            st = hf_term_value(kind, in, n_real, c, x, u, f, &value);
        if (st != 0) return st;
        for (e = 0; e < n_eq; ++e) out[eq[e]] += value;
    }
    return 0;
}
