/*
 * The diagnosed effects that add a term to the state derivatives, evaluated in C (effects.c).
 */
#ifndef HYBRIDFMU_EFFECTS_H
#define HYBRIDFMU_EFFECTS_H

#include <stddef.h>

/* Returned by hf_effects_add for a program with an unknown term kind. */
#define HF_EFFECT_ERR_PROGRAM (-4)

/* The model's derivatives dx (nx,) at the current state with the inputs u (nu,); 0 on success. */
typedef int (*hf_effect_eval_fn)(void *context, const double *u, double *dx);

/* out (nx,) = the sum of the program's terms at the state x (nx,), the inputs u (nu,) and the model's
   derivatives f (nx,) there. work: nu + nx doubles. eval evaluates the model with changed inputs at the same
   state (context is passed on to it); a program with such a term leaves the model's inputs changed, so the caller
   sets them back. Returns 0, HF_EFFECT_ERR_PROGRAM for an unknown term kind, or eval's nonzero status. */
int hf_effects_add(const long long *code, size_t n_code, const double *reals, size_t nx, size_t nu,
                   const double *x, const double *u, const double *f, double *out, double *work,
                   hf_effect_eval_fn eval, void *context);

#endif
