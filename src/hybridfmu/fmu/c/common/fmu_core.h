/*
 * Generic part of the hybridfmu FMI 2.0 Model-Exchange FMUs.
 *
 * fmu_core.c implements the whole FMI 2.0 API (state machine, argument checks, logging,
 * variable access, FMU state get/set/serialisation). A model (e.g. ipbmotor/IPBMotor.c)
 * implements only the functions declared under "Provided by the model" below.
 *
 * The build (hybridfmu/fmu/build.py) derives these macros from the model's
 * modelDescription.xml and passes them on the compiler command line, so the XML is the
 * single source of the model's interface facts; the model asserts at compile time that its
 * own tables agree with them:
 *   MODEL_IDENTIFIER                        string, e.g. "IPBMotor"
 *   MODEL_GUID                              string, the guid attribute
 *   MODEL_N_STATES                          number of continuous states
 *   MODEL_N_EVENT_INDICATORS                numberOfEventIndicators
 *   MODEL_N_REALS, MODEL_N_INTEGERS         number of Real / Integer model variables
 *   MODEL_PROVIDES_DIRECTIONAL_DERIVATIVE   0 or 1
 */
#ifndef HYBRIDFMU_FMU_CORE_H
#define HYBRIDFMU_FMU_CORE_H

#include <stddef.h>

#include "fmi2Functions.h"

#if !defined(MODEL_IDENTIFIER) || !defined(MODEL_GUID) || !defined(MODEL_N_STATES) || \
    !defined(MODEL_N_EVENT_INDICATORS) || !defined(MODEL_N_REALS) || !defined(MODEL_N_INTEGERS) || \
    !defined(MODEL_PROVIDES_DIRECTIONAL_DERIVATIVE)
#error "compile with the MODEL_* macros derived from modelDescription.xml (see hybridfmu/fmu/build.py)"
#endif

/* C has no zero-length arrays: storage for a count that may be 0. */
#define FMU_ARRAY_LEN(n) ((n) > 0 ? (n) : 1)

/* Length of the buffers for error messages. */
#define FMU_MESSAGE_LEN 512

typedef enum { VAR_REAL, VAR_INTEGER } VarType;

typedef enum {
    VAR_PARAMETER,  /* causality parameter, variability tunable */
    VAR_INPUT,      /* causality input, variability continuous */
    VAR_STATE,      /* continuous state (causality local, initial exact) */
    VAR_DERIVATIVE, /* state derivative (calculated) */
    VAR_OUTPUT      /* causality output (calculated) */
} VarKind;

/* One model variable: its value reference, name, type, role and storage slot. */
typedef struct {
    fmi2ValueReference vr;
    const char *name;
    VarType type;
    VarKind kind;
    size_t index; /* into ModelData.real (VAR_REAL) or ModelData.integer (VAR_INTEGER) */
    double start; /* start value; for calculated variables the value after a reset */
} VarInfo;

/* Everything that defines the model's values: storage of all variables. */
typedef struct {
    double real[FMU_ARRAY_LEN(MODEL_N_REALS)];
    int integer[FMU_ARRAY_LEN(MODEL_N_INTEGERS)];
} ModelData;

/* Phases of the FMI 2.0 Model-Exchange state machine (bit flags, so a set is a mask). */
typedef enum {
    PHASE_INSTANTIATED = 1,
    PHASE_INITIALIZATION = 2,
    PHASE_EVENT = 4,
    PHASE_CONTINUOUS = 8,
    PHASE_TERMINATED = 16
} Phase;

/* The FMU state: what fmi2GetFMUstate saves and fmi2SetFMUstate restores. Plain data. */
typedef struct {
    int phase; /* a Phase */
    double time_s;
    ModelData data;
} InstanceState;

/* What the model asks of the importer at the end of an event iteration (fmi2NewDiscreteStates).
   The core clears it before every call of model_event_update, which may set its fields. */
typedef struct {
    int next_event_time_defined; /* 1: a time event is due at next_event_time_s */
    double next_event_time_s;    /* absolute simulation time of the next time event, s */
    int terminate;               /* 1: the simulation must end now (terminateSimulation) */
} EventRequest;

typedef struct ModelInstance {
    unsigned magic; /* FMU_INSTANCE_MAGIC while the instance is alive */
    char *instance_name;
    fmi2CallbackLogger logger;
    fmi2CallbackAllocateMemory allocate_memory;
    fmi2CallbackFreeMemory free_memory;
    fmi2ComponentEnvironment environment;
    int logging_on;
    unsigned log_categories; /* bit i set: category i of fmu_log_category_names enabled */
    InstanceState state;
    EventRequest request; /* filled by model_event_update, reported by fmi2NewDiscreteStates */
} ModelInstance;

/* Log categories (modelDescription.xml, <LogCategories>). */
enum { LOG_EVENTS = 0, LOG_STATUS_WARNING = 1, LOG_STATUS_ERROR = 2, LOG_N_CATEGORIES = 3 };

/* Send a message through the importer's logger. Errors and warnings are always sent;
   messages of category LOG_EVENTS only when debug logging is on for that category. */
void fmu_log(const ModelInstance *instance, fmi2Status status, int category, const char *format, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 4, 5)))
#endif
    ;

/* ---------------------------------------------------------------- Provided by the model */

/* All model variables, sorted by value reference; model_n_variables entries. */
extern const VarInfo model_variables[];
extern const size_t model_n_variables;

/* Real storage index of each state, of each state derivative, and the state nominals. */
extern const size_t model_state_index[FMU_ARRAY_LEN(MODEL_N_STATES)];
extern const size_t model_derivative_index[FMU_ARRAY_LEN(MODEL_N_STATES)];
extern const double model_state_nominal[FMU_ARRAY_LEN(MODEL_N_STATES)];

/* Check one value about to be set (finite values only reach it). Return 0 if acceptable,
   else 1 and a message naming the variable and what is expected. */
int model_check_value(const VarInfo *variable, double value, char *message, size_t size);

/* Check relations between parameters (e.g. theta_min < theta_max), after every parameter has
   passed model_check_value. Same convention. */
int model_check_parameter_relations(const ModelData *data, char *message, size_t size);

/* Compute the state derivatives and the outputs from states, inputs, parameters and
   discrete states, and store them in data. */
void model_calculate(ModelData *data);

/* Event indicators (MODEL_N_EVENT_INDICATORS values) of the current values. */
void model_event_indicators(const ModelData *data, double indicators[]);

/* Event iteration (fmi2NewDiscreteStates): update discrete states, possibly re-initialise
   continuous states. Return 1 if continuous state values changed, else 0. The model may announce
   its next time event or ask to terminate through instance->request (cleared before the call);
   the current time is instance->state.time_s. */
int model_event_update(ModelInstance *instance);

/* After an integrator step: return 1 if the values are inconsistent with the discrete
   states so that event mode must be entered (a safety net for missed state events). */
int model_step_event_needed(const ModelData *data);

/* Optional: the core links a default that returns 0 when the model does not define it.
   After an integrator step (fmi2CompletedIntegratorStep), return 1 to ask the importer to
   terminate the simulation (terminateSimulation); time and values are in instance->state. */
int model_step_terminate_needed(const ModelInstance *instance);

#if MODEL_PROVIDES_DIRECTIONAL_DERIVATIVE
/* dv_unknown[i] = sum_j d(unknown_i)/d(known_j) * dv_known[j] at the current values.
   Return 0 on success, else 1 and a message (e.g. an unsupported known or unknown). */
int model_directional_derivative(const ModelData *data, const VarInfo *const unknowns[], size_t n_unknowns,
                                 const VarInfo *const knowns[], size_t n_knowns, const double dv_known[],
                                 double dv_unknown[], char *message, size_t size);
#endif

#endif
