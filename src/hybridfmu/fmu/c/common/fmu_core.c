/*
 * The FMI 2.0 Model-Exchange API for a model that implements fmu_core.h.
 *
 * Conventions:
 * - Every function checks its component, the phase of the state machine, NULL pointers,
 *   array lengths and value references, and returns fmi2Error with a log message naming the
 *   function and the problem. A call that returns fmi2Error has no effect on the instance
 *   (values are checked before any is stored), so the importer may correct and retry.
 * - Non-finite Real values (NaN, inf) are rejected wherever values are set.
 * - Parameters are tunable: settable before initialisation, in initialisation mode and in
 *   event mode; the cross-checks of all parameters run when initialisation mode is left and
 *   at every event iteration.
 * - The co-simulation functions exist (the standard header declares them) and return
 *   fmi2Error: this is a Model-Exchange FMU.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "fmu_core.h"

#define FMU_INSTANCE_MAGIC 0x46a7e301u
#define FMU_STATE_MAGIC 0x46a7e302u

/* Serialised FMU state: header then the InstanceState bytes. */
#define SERIAL_TAG "hybridfmu-state"
#define SERIAL_FORMAT_VERSION 1u
#define SERIAL_IDENTIFIER_LEN 64

typedef struct {
    char tag[16];                         /* SERIAL_TAG, zero padded */
    unsigned format_version;              /* SERIAL_FORMAT_VERSION */
    unsigned payload_size;                /* sizeof(InstanceState) */
    char identifier[SERIAL_IDENTIFIER_LEN]; /* MODEL_IDENTIFIER, zero padded */
    char guid[SERIAL_IDENTIFIER_LEN];     /* MODEL_GUID, zero padded */
} SerialHeader;

/* A saved FMU state (fmi2FMUstate points to one). */
typedef struct {
    unsigned magic; /* FMU_STATE_MAGIC */
    InstanceState state;
} SavedState;

#define ALL_PHASES (PHASE_INSTANTIATED | PHASE_INITIALIZATION | PHASE_EVENT | PHASE_CONTINUOUS | PHASE_TERMINATED)
#define AFTER_INSTANTIATION (PHASE_INITIALIZATION | PHASE_EVENT | PHASE_CONTINUOUS | PHASE_TERMINATED)

static const char *const log_category_names[LOG_N_CATEGORIES] = {"logEvents", "logStatusWarning",
                                                                  "logStatusError"};

/* ------------------------------------------------------------------------ logging */

static const char *status_category(fmi2Status status, int category) {
    if (status == fmi2Error || status == fmi2Fatal) return log_category_names[LOG_STATUS_ERROR];
    if (status == fmi2Warning) return log_category_names[LOG_STATUS_WARNING];
    return log_category_names[category];
}

/* Format into buffer and double every '%' (the logger treats the message as a format). */
static void format_message(char *buffer, size_t size, const char *format, va_list args) {
    char raw[FMU_MESSAGE_LEN];
    vsnprintf(raw, sizeof raw, format, args);
    size_t j = 0;
    for (size_t i = 0; raw[i] != '\0' && j + 2 < size; ++i) {
        buffer[j++] = raw[i];
        if (raw[i] == '%') buffer[j++] = '%';
    }
    buffer[j] = '\0';
}

static void log_without_instance(const fmi2CallbackFunctions *functions, fmi2String instance_name,
                                 fmi2Status status, const char *format, ...) {
    if (functions == NULL || functions->logger == NULL) return;
    char message[2 * FMU_MESSAGE_LEN];
    va_list args;
    va_start(args, format);
    format_message(message, sizeof message, format, args);
    va_end(args);
    functions->logger(functions->componentEnvironment, instance_name != NULL ? instance_name : "?", status,
                      status_category(status, LOG_STATUS_ERROR), message);
}

void fmu_log(const ModelInstance *instance, fmi2Status status, int category, const char *format, ...) {
    if (instance == NULL || instance->logger == NULL) return;
    int always = (status == fmi2Error || status == fmi2Fatal || status == fmi2Warning);
    if (!always && !(instance->logging_on && (instance->log_categories & (1u << category)))) return;
    char message[2 * FMU_MESSAGE_LEN];
    va_list args;
    va_start(args, format);
    format_message(message, sizeof message, format, args);
    va_end(args);
    instance->logger(instance->environment, instance->instance_name, status, status_category(status, category),
                     message);
}

/* ------------------------------------------------------------------------ helpers */

static const char *phase_name(int phase) {
    switch (phase) {
    case PHASE_INSTANTIATED: return "the instantiated state (before initialisation)";
    case PHASE_INITIALIZATION: return "initialisation mode";
    case PHASE_EVENT: return "event mode";
    case PHASE_CONTINUOUS: return "continuous-time mode";
    case PHASE_TERMINATED: return "the terminated state";
    default: return "an unknown state";
    }
}

static const char *kind_name(VarKind kind) {
    switch (kind) {
    case VAR_PARAMETER: return "parameter";
    case VAR_INPUT: return "input";
    case VAR_STATE: return "continuous state";
    case VAR_DERIVATIVE: return "state derivative";
    case VAR_OUTPUT: return "output";
    }
    return "variable";
}

/* The component as a live instance, or NULL (nothing can be logged then). */
static ModelInstance *as_instance(fmi2Component c) {
    ModelInstance *instance = (ModelInstance *)c;
    if (instance == NULL || instance->magic != FMU_INSTANCE_MAGIC) return NULL;
    return instance;
}

/* The instance if it is live and in one of the phases of mask, else NULL (logged). */
static ModelInstance *enter(fmi2Component c, const char *function, int mask) {
    ModelInstance *instance = as_instance(c);
    if (instance == NULL) return NULL;
    if (!(instance->state.phase & mask)) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: not allowed in %s", function,
                phase_name(instance->state.phase));
        return NULL;
    }
    return instance;
}

static int null_argument(ModelInstance *instance, const char *function, const void *pointer, const char *argument) {
    if (pointer != NULL) return 0;
    fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: argument %s is NULL", function, argument);
    return 1;
}

static const VarInfo *find_variable(fmi2ValueReference vr) {
    size_t lo = 0, hi = model_n_variables;
    while (lo < hi) { /* model_variables is sorted by value reference */
        size_t mid = lo + (hi - lo) / 2;
        if (model_variables[mid].vr == vr) return &model_variables[mid];
        if (model_variables[mid].vr < vr) lo = mid + 1;
        else hi = mid;
    }
    return NULL;
}

static const char *type_name(VarType type) { return type == VAR_REAL ? "Real" : "Integer"; }

/* The variable of type `type` with value reference vr, or NULL (logged). */
static const VarInfo *lookup(ModelInstance *instance, const char *function, fmi2ValueReference vr, VarType type) {
    const VarInfo *variable = find_variable(vr);
    if (variable == NULL) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: unknown value reference %u", function, vr);
        return NULL;
    }
    if (variable->type != type) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: value reference %u (%s) is an %s variable, not %s",
                function, vr, variable->name, type_name(variable->type), type_name(type));
        return NULL;
    }
    return variable;
}

static int needs_calculation(VarKind kind) { return kind == VAR_DERIVATIVE || kind == VAR_OUTPUT; }

/* Phases in which a variable of this kind may be set with fmi2SetReal/fmi2SetInteger. */
static int settable_mask(VarKind kind) {
    switch (kind) {
    case VAR_PARAMETER: return PHASE_INSTANTIATED | PHASE_INITIALIZATION | PHASE_EVENT;
    case VAR_INPUT: return PHASE_INSTANTIATED | PHASE_INITIALIZATION | PHASE_EVENT | PHASE_CONTINUOUS;
    case VAR_STATE: return PHASE_INSTANTIATED | PHASE_INITIALIZATION;
    default: return 0;
    }
}

static void set_start_values(InstanceState *state) {
    memset(state, 0, sizeof *state);
    state->phase = PHASE_INSTANTIATED;
    state->time_s = 0.0;
    for (size_t i = 0; i < model_n_variables; ++i) {
        const VarInfo *v = &model_variables[i];
        if (v->type == VAR_REAL) state->data.real[v->index] = v->start;
        else state->data.integer[v->index] = (int)v->start;
    }
}

/* Each parameter finite and acceptable to the model, then the relations between them.
   Return 0 if all hold, else 1 and a message naming the parameter(s). */
static int parameters_invalid(const ModelData *data, char *message, size_t size) {
    for (size_t i = 0; i < model_n_variables; ++i) {
        const VarInfo *v = &model_variables[i];
        if (v->kind != VAR_PARAMETER) continue;
        double value = data->real[v->index];
        if (!isfinite(value)) {
            snprintf(message, size, "parameter \"%s\" = %g is not a finite number", v->name, value);
            return 1;
        }
        if (model_check_value(v, value, message, size)) return 1;
    }
    return model_check_parameter_relations(data, message, size);
}

static fmi2Status check_all_parameters(ModelInstance *instance, const char *function) {
    char message[FMU_MESSAGE_LEN];
    if (parameters_invalid(&instance->state.data, message, sizeof message)) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: %s", function, message);
        return fmi2Error;
    }
    return fmi2OK;
}

static fmi2Status co_simulation_only(fmi2Component c, const char *function) {
    ModelInstance *instance = as_instance(c);
    if (instance != NULL)
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR,
                "%s: this is a Model-Exchange FMU; co-simulation functions are not supported", function);
    return fmi2Error;
}

/* ------------------------------------------------------------------------ inquiry, logging */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    ModelInstance *instance = enter(c, "fmi2SetDebugLogging", ALL_PHASES);
    if (instance == NULL) return fmi2Error;
    if (nCategories > 0 && null_argument(instance, "fmi2SetDebugLogging", categories, "categories")) return fmi2Error;
    unsigned selected = 0;
    for (size_t i = 0; i < nCategories; ++i) {
        int found = -1;
        if (categories[i] != NULL)
            for (int k = 0; k < LOG_N_CATEGORIES; ++k)
                if (strcmp(categories[i], log_category_names[k]) == 0) found = k;
        if (found < 0) {
            fmu_log(instance, fmi2Error, LOG_STATUS_ERROR,
                    "fmi2SetDebugLogging: unknown log category \"%s\" (known: logEvents, logStatusWarning, "
                    "logStatusError)", categories[i] != NULL ? categories[i] : "(NULL)");
            return fmi2Error;
        }
        selected |= 1u << found;
    }
    if (nCategories == 0) selected = (1u << LOG_N_CATEGORIES) - 1u;
    if (loggingOn) {
        instance->logging_on = 1;
        instance->log_categories |= selected;
    } else {
        instance->log_categories &= ~selected;
        instance->logging_on = instance->log_categories != 0;
    }
    return fmi2OK;
}

/* ------------------------------------------------------------------------ creation, destruction */

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    (void)fmuResourceLocation; /* the models need no resources */
    (void)visible;
    if (functions == NULL) return NULL;
    if (functions->allocateMemory == NULL || functions->freeMemory == NULL) {
        log_without_instance(functions, instanceName, fmi2Error,
                             "fmi2Instantiate: the callbacks allocateMemory and freeMemory are required");
        return NULL;
    }
    if (instanceName == NULL || instanceName[0] == '\0') {
        log_without_instance(functions, instanceName, fmi2Error, "fmi2Instantiate: instanceName is empty");
        return NULL;
    }
    if (fmuType != fmi2ModelExchange) {
        log_without_instance(functions, instanceName, fmi2Error,
                             "fmi2Instantiate: %s supports Model Exchange only (fmuType fmi2ModelExchange)",
                             MODEL_IDENTIFIER);
        return NULL;
    }
    if (fmuGUID == NULL || strcmp(fmuGUID, MODEL_GUID) != 0) {
        log_without_instance(functions, instanceName, fmi2Error,
                             "fmi2Instantiate: GUID \"%s\" does not match the GUID \"%s\" of %s",
                             fmuGUID != NULL ? fmuGUID : "(NULL)", MODEL_GUID, MODEL_IDENTIFIER);
        return NULL;
    }
    ModelInstance *instance = (ModelInstance *)functions->allocateMemory(1, sizeof(ModelInstance));
    size_t name_length = strlen(instanceName);
    char *name = (char *)functions->allocateMemory(name_length + 1, sizeof(char));
    if (instance == NULL || name == NULL) {
        if (instance != NULL) functions->freeMemory(instance);
        if (name != NULL) functions->freeMemory(name);
        log_without_instance(functions, instanceName, fmi2Error, "fmi2Instantiate: out of memory");
        return NULL;
    }
    memcpy(name, instanceName, name_length + 1);
    memset(instance, 0, sizeof *instance);
    instance->magic = FMU_INSTANCE_MAGIC;
    instance->instance_name = name;
    instance->logger = functions->logger;
    instance->allocate_memory = functions->allocateMemory;
    instance->free_memory = functions->freeMemory;
    instance->environment = functions->componentEnvironment;
    instance->logging_on = loggingOn ? 1 : 0;
    instance->log_categories = loggingOn ? (1u << LOG_N_CATEGORIES) - 1u : 0u;
    set_start_values(&instance->state);
    return instance;
}

void fmi2FreeInstance(fmi2Component c) {
    ModelInstance *instance = as_instance(c);
    if (instance == NULL) return;
    fmi2CallbackFreeMemory free_memory = instance->free_memory;
    instance->magic = 0;
    free_memory(instance->instance_name);
    free_memory(instance);
}

/* ------------------------------------------------------------------------ initialisation, end */

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    ModelInstance *instance = enter(c, "fmi2SetupExperiment", PHASE_INSTANTIATED);
    if (instance == NULL) return fmi2Error;
    if (toleranceDefined && !(isfinite(tolerance) && tolerance > 0.0)) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "fmi2SetupExperiment: tolerance %g must be finite and > 0",
                tolerance);
        return fmi2Error;
    }
    if (!isfinite(startTime)) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "fmi2SetupExperiment: startTime %g is not finite", startTime);
        return fmi2Error;
    }
    if (stopTimeDefined && !(isfinite(stopTime) && stopTime >= startTime)) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR,
                "fmi2SetupExperiment: stopTime %g must be finite and >= startTime %g", stopTime, startTime);
        return fmi2Error;
    }
    instance->state.time_s = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    ModelInstance *instance = enter(c, "fmi2EnterInitializationMode", PHASE_INSTANTIATED);
    if (instance == NULL) return fmi2Error;
    instance->state.phase = PHASE_INITIALIZATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    ModelInstance *instance = enter(c, "fmi2ExitInitializationMode", PHASE_INITIALIZATION);
    if (instance == NULL) return fmi2Error;
    if (check_all_parameters(instance, "fmi2ExitInitializationMode") != fmi2OK) return fmi2Error;
    instance->state.phase = PHASE_EVENT;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    ModelInstance *instance = enter(c, "fmi2Terminate", PHASE_EVENT | PHASE_CONTINUOUS);
    if (instance == NULL) return fmi2Error;
    instance->state.phase = PHASE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    ModelInstance *instance = enter(c, "fmi2Reset", ALL_PHASES);
    if (instance == NULL) return fmi2Error;
    set_start_values(&instance->state);
    return fmi2OK;
}

/* ------------------------------------------------------------------------ getting and setting values */

static fmi2Status get_values(fmi2Component c, const char *function, VarType type, const fmi2ValueReference vr[],
                             size_t nvr, double *reals, int *integers) {
    ModelInstance *instance = enter(c, function, AFTER_INSTANTIATION);
    if (instance == NULL) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    if (null_argument(instance, function, vr, "vr") ||
        null_argument(instance, function, type == VAR_REAL ? (const void *)reals : (const void *)integers, "value"))
        return fmi2Error;
    int calculate = 0;
    for (size_t i = 0; i < nvr; ++i) {
        const VarInfo *variable = lookup(instance, function, vr[i], type);
        if (variable == NULL) return fmi2Error;
        calculate |= needs_calculation(variable->kind);
    }
    if (calculate) model_calculate(&instance->state.data);
    for (size_t i = 0; i < nvr; ++i) {
        const VarInfo *variable = find_variable(vr[i]);
        if (type == VAR_REAL) reals[i] = instance->state.data.real[variable->index];
        else integers[i] = instance->state.data.integer[variable->index];
    }
    return fmi2OK;
}

static fmi2Status set_values(fmi2Component c, const char *function, VarType type, const fmi2ValueReference vr[],
                             size_t nvr, const double *reals, const int *integers) {
    ModelInstance *instance =
        enter(c, function, PHASE_INSTANTIATED | PHASE_INITIALIZATION | PHASE_EVENT | PHASE_CONTINUOUS);
    if (instance == NULL) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    if (null_argument(instance, function, vr, "vr") ||
        null_argument(instance, function, type == VAR_REAL ? (const void *)reals : (const void *)integers, "value"))
        return fmi2Error;
    /* check everything first, so that a failing call changes nothing */
    for (size_t i = 0; i < nvr; ++i) {
        const VarInfo *variable = lookup(instance, function, vr[i], type);
        if (variable == NULL) return fmi2Error;
        if (!(settable_mask(variable->kind) & instance->state.phase)) {
            if (settable_mask(variable->kind) == 0)
                fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: %s \"%s\" is calculated and cannot be set",
                        function, kind_name(variable->kind), variable->name);
            else
                fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: %s \"%s\" cannot be set in %s%s", function,
                        kind_name(variable->kind), variable->name, phase_name(instance->state.phase),
                        variable->kind == VAR_STATE ? " (use fmi2SetContinuousStates)" : "");
            return fmi2Error;
        }
        double value = type == VAR_REAL ? reals[i] : (double)integers[i];
        if (!isfinite(value)) {
            fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: %s \"%s\" = %g is not a finite number", function,
                    kind_name(variable->kind), variable->name, value);
            return fmi2Error;
        }
        char message[FMU_MESSAGE_LEN];
        if (model_check_value(variable, value, message, sizeof message)) {
            fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: %s", function, message);
            return fmi2Error;
        }
    }
    for (size_t i = 0; i < nvr; ++i) {
        const VarInfo *variable = find_variable(vr[i]);
        if (type == VAR_REAL) instance->state.data.real[variable->index] = reals[i];
        else instance->state.data.integer[variable->index] = integers[i];
    }
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    return get_values(c, "fmi2GetReal", VAR_REAL, vr, nvr, value, NULL);
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    return get_values(c, "fmi2GetInteger", VAR_INTEGER, vr, nvr, NULL, value);
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    return set_values(c, "fmi2SetReal", VAR_REAL, vr, nvr, value, NULL);
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    return set_values(c, "fmi2SetInteger", VAR_INTEGER, vr, nvr, NULL, value);
}

/* The models have no Boolean or String variables: every value reference is unknown. */
static fmi2Status no_variables_of_type(fmi2Component c, const char *function, int mask,
                                       const fmi2ValueReference vr[], size_t nvr, const void *value,
                                       const char *type) {
    ModelInstance *instance = enter(c, function, mask);
    if (instance == NULL) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    if (null_argument(instance, function, vr, "vr") || null_argument(instance, function, value, "value"))
        return fmi2Error;
    fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: unknown value reference %u (%s has no %s variables)",
            function, vr[0], MODEL_IDENTIFIER, type);
    return fmi2Error;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    return no_variables_of_type(c, "fmi2GetBoolean", AFTER_INSTANTIATION, vr, nvr, value, "Boolean");
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    return no_variables_of_type(c, "fmi2GetString", AFTER_INSTANTIATION, vr, nvr, value, "String");
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    return no_variables_of_type(c, "fmi2SetBoolean",
                                PHASE_INSTANTIATED | PHASE_INITIALIZATION | PHASE_EVENT | PHASE_CONTINUOUS, vr, nvr,
                                value, "Boolean");
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    return no_variables_of_type(c, "fmi2SetString",
                                PHASE_INSTANTIATED | PHASE_INITIALIZATION | PHASE_EVENT | PHASE_CONTINUOUS, vr, nvr,
                                value, "String");
}

/* ------------------------------------------------------------------------ FMU state */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    ModelInstance *instance = enter(c, "fmi2GetFMUstate", ALL_PHASES);
    if (instance == NULL) return fmi2Error;
    if (null_argument(instance, "fmi2GetFMUstate", FMUstate, "FMUstate")) return fmi2Error;
    SavedState *saved = (SavedState *)*FMUstate;
    if (saved != NULL && saved->magic != FMU_STATE_MAGIC) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR,
                "fmi2GetFMUstate: *FMUstate is neither NULL nor a state of this FMU");
        return fmi2Error;
    }
    if (saved == NULL) {
        saved = (SavedState *)instance->allocate_memory(1, sizeof(SavedState));
        if (saved == NULL) {
            fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "fmi2GetFMUstate: out of memory");
            return fmi2Error;
        }
    }
    saved->magic = FMU_STATE_MAGIC;
    saved->state = instance->state;
    *FMUstate = saved;
    return fmi2OK;
}

static const SavedState *as_saved_state(ModelInstance *instance, const char *function, fmi2FMUstate FMUstate) {
    const SavedState *saved = (const SavedState *)FMUstate;
    if (null_argument(instance, function, FMUstate, "FMUstate")) return NULL;
    if (saved->magic != FMU_STATE_MAGIC) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: FMUstate is not a state of this FMU", function);
        return NULL;
    }
    return saved;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    ModelInstance *instance = enter(c, "fmi2SetFMUstate", ALL_PHASES);
    if (instance == NULL) return fmi2Error;
    const SavedState *saved = as_saved_state(instance, "fmi2SetFMUstate", FMUstate);
    if (saved == NULL) return fmi2Error;
    instance->state = saved->state;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    ModelInstance *instance = enter(c, "fmi2FreeFMUstate", ALL_PHASES);
    if (instance == NULL) return fmi2Error;
    if (null_argument(instance, "fmi2FreeFMUstate", FMUstate, "FMUstate")) return fmi2Error;
    if (*FMUstate == NULL) return fmi2OK;
    SavedState *saved = (SavedState *)*FMUstate;
    if (saved->magic != FMU_STATE_MAGIC) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "fmi2FreeFMUstate: *FMUstate is not a state of this FMU");
        return fmi2Error;
    }
    saved->magic = 0;
    instance->free_memory(saved);
    *FMUstate = NULL;
    return fmi2OK;
}

static size_t serialized_size(void) { return sizeof(SerialHeader) + sizeof(InstanceState); }

/* Copy text into a zero-filled field of `size` bytes, truncated so that it stays terminated. */
static void copy_text(char *field, size_t size, const char *text) {
    size_t length = strlen(text);
    memcpy(field, text, length < size - 1 ? length : size - 1);
}

static void make_header(SerialHeader *header) {
    memset(header, 0, sizeof *header);
    copy_text(header->tag, sizeof header->tag, SERIAL_TAG);
    header->format_version = SERIAL_FORMAT_VERSION;
    header->payload_size = (unsigned)sizeof(InstanceState);
    copy_text(header->identifier, sizeof header->identifier, MODEL_IDENTIFIER);
    copy_text(header->guid, sizeof header->guid, MODEL_GUID);
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    ModelInstance *instance = enter(c, "fmi2SerializedFMUstateSize", ALL_PHASES);
    if (instance == NULL) return fmi2Error;
    if (as_saved_state(instance, "fmi2SerializedFMUstateSize", FMUstate) == NULL) return fmi2Error;
    if (null_argument(instance, "fmi2SerializedFMUstateSize", size, "size")) return fmi2Error;
    *size = serialized_size();
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size) {
    ModelInstance *instance = enter(c, "fmi2SerializeFMUstate", ALL_PHASES);
    if (instance == NULL) return fmi2Error;
    const SavedState *saved = as_saved_state(instance, "fmi2SerializeFMUstate", FMUstate);
    if (saved == NULL) return fmi2Error;
    if (null_argument(instance, "fmi2SerializeFMUstate", serializedState, "serializedState")) return fmi2Error;
    if (size < serialized_size()) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR,
                "fmi2SerializeFMUstate: buffer of %zu bytes is too small (%zu needed)", size, serialized_size());
        return fmi2Error;
    }
    SerialHeader header;
    make_header(&header);
    memcpy(serializedState, &header, sizeof header);
    memcpy(serializedState + sizeof header, &saved->state, sizeof saved->state);
    return fmi2OK;
}

static int valid_phase(int phase) {
    return phase == PHASE_INSTANTIATED || phase == PHASE_INITIALIZATION || phase == PHASE_EVENT ||
           phase == PHASE_CONTINUOUS || phase == PHASE_TERMINATED;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    const char *function = "fmi2DeSerializeFMUstate";
    ModelInstance *instance = enter(c, function, ALL_PHASES);
    if (instance == NULL) return fmi2Error;
    if (null_argument(instance, function, serializedState, "serializedState") ||
        null_argument(instance, function, FMUstate, "FMUstate"))
        return fmi2Error;
    if (size != serialized_size()) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR,
                "%s: %zu bytes given, a serialized state of %s has %zu bytes", function, size, MODEL_IDENTIFIER,
                serialized_size());
        return fmi2Error;
    }
    SerialHeader expected, header;
    make_header(&expected);
    memcpy(&header, serializedState, sizeof header);
    if (memcmp(&header, &expected, sizeof header) != 0) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR,
                "%s: the bytes are not a serialized state of %s (format %u, GUID %s)", function, MODEL_IDENTIFIER,
                SERIAL_FORMAT_VERSION, MODEL_GUID);
        return fmi2Error;
    }
    InstanceState state;
    memcpy(&state, serializedState + sizeof header, sizeof state);
    if (!valid_phase(state.phase) || !isfinite(state.time_s)) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: the serialized state is corrupt", function);
        return fmi2Error;
    }
    for (size_t i = 0; i < MODEL_N_REALS; ++i) {
        if (!isfinite(state.data.real[i])) {
            fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: the serialized state holds a non-finite value",
                    function);
            return fmi2Error;
        }
    }
    SavedState *saved = (SavedState *)*FMUstate;
    if (saved != NULL && saved->magic != FMU_STATE_MAGIC) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: *FMUstate is neither NULL nor a state of this FMU",
                function);
        return fmi2Error;
    }
    if (saved == NULL) {
        saved = (SavedState *)instance->allocate_memory(1, sizeof(SavedState));
        if (saved == NULL) {
            fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: out of memory", function);
            return fmi2Error;
        }
    }
    saved->magic = FMU_STATE_MAGIC;
    saved->state = state;
    *FMUstate = saved;
    return fmi2OK;
}

/* ------------------------------------------------------------------------ directional derivatives */

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    const char *function = "fmi2GetDirectionalDerivative";
    ModelInstance *instance = enter(c, function, AFTER_INSTANTIATION);
    if (instance == NULL) return fmi2Error;
#if MODEL_PROVIDES_DIRECTIONAL_DERIVATIVE
    if (nUnknown == 0) return fmi2OK;
    if (null_argument(instance, function, vUnknown_ref, "vUnknown_ref") ||
        null_argument(instance, function, dvUnknown, "dvUnknown"))
        return fmi2Error;
    if (nKnown > 0 && (null_argument(instance, function, vKnown_ref, "vKnown_ref") ||
                       null_argument(instance, function, dvKnown, "dvKnown")))
        return fmi2Error;
    /* small fixed buffers: at most every Real variable once (duplicates are allowed) */
    enum { MAX_REFS = 8 * FMU_ARRAY_LEN(MODEL_N_REALS) };
    const VarInfo *unknowns[MAX_REFS];
    const VarInfo *knowns[MAX_REFS];
    if (nUnknown > MAX_REFS || nKnown > MAX_REFS) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: at most %d unknowns and knowns per call", function,
                (int)MAX_REFS);
        return fmi2Error;
    }
    for (size_t i = 0; i < nUnknown; ++i)
        if ((unknowns[i] = lookup(instance, function, vUnknown_ref[i], VAR_REAL)) == NULL) return fmi2Error;
    for (size_t j = 0; j < nKnown; ++j) {
        if ((knowns[j] = lookup(instance, function, vKnown_ref[j], VAR_REAL)) == NULL) return fmi2Error;
        if (!isfinite(dvKnown[j])) {
            fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: dvKnown[%zu] is not finite", function, j);
            return fmi2Error;
        }
    }
    char message[FMU_MESSAGE_LEN];
    if (model_directional_derivative(&instance->state.data, unknowns, nUnknown, knowns, nKnown, dvKnown, dvUnknown,
                                     message, sizeof message)) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: %s", function, message);
        return fmi2Error;
    }
    return fmi2OK;
#else
    (void)vUnknown_ref; (void)nUnknown; (void)vKnown_ref; (void)nKnown; (void)dvKnown; (void)dvUnknown;
    fmu_log(instance, fmi2Error, LOG_STATUS_ERROR,
            "%s: %s does not provide directional derivatives (providesDirectionalDerivative=\"false\")", function,
            MODEL_IDENTIFIER);
    return fmi2Error;
#endif
}

/* ------------------------------------------------------------------------ Model Exchange */

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    ModelInstance *instance = enter(c, "fmi2EnterEventMode", PHASE_EVENT | PHASE_CONTINUOUS);
    if (instance == NULL) return fmi2Error;
    instance->state.phase = PHASE_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *fmi2eventInfo) {
    ModelInstance *instance = enter(c, "fmi2NewDiscreteStates", PHASE_EVENT);
    if (instance == NULL) return fmi2Error;
    if (null_argument(instance, "fmi2NewDiscreteStates", fmi2eventInfo, "fmi2eventInfo")) return fmi2Error;
    if (check_all_parameters(instance, "fmi2NewDiscreteStates") != fmi2OK) return fmi2Error;
    memset(&instance->request, 0, sizeof instance->request);
    int states_changed = model_event_update(instance);
    const EventRequest *request = &instance->request;
    int next_time_valid = request->next_event_time_defined && isfinite(request->next_event_time_s) &&
                          request->next_event_time_s > instance->state.time_s;
    if (request->next_event_time_defined && !next_time_valid) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR,
                "fmi2NewDiscreteStates: the model announced its next time event at t = %g s, "
                "expected a finite time after the current time %g s",
                request->next_event_time_s, instance->state.time_s);
        return fmi2Error;
    }
    fmi2eventInfo->newDiscreteStatesNeeded = fmi2False;
    fmi2eventInfo->terminateSimulation = request->terminate ? fmi2True : fmi2False;
    fmi2eventInfo->nominalsOfContinuousStatesChanged = fmi2False;
    fmi2eventInfo->valuesOfContinuousStatesChanged = states_changed ? fmi2True : fmi2False;
    fmi2eventInfo->nextEventTimeDefined = next_time_valid ? fmi2True : fmi2False;
    fmi2eventInfo->nextEventTime = next_time_valid ? request->next_event_time_s : 0.0;
    if (request->terminate)
        fmu_log(instance, fmi2OK, LOG_EVENTS, "fmi2NewDiscreteStates: the model asks to terminate at t = %g s",
                instance->state.time_s);
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    ModelInstance *instance = enter(c, "fmi2EnterContinuousTimeMode", PHASE_EVENT);
    if (instance == NULL) return fmi2Error;
    if (check_all_parameters(instance, "fmi2EnterContinuousTimeMode") != fmi2OK) return fmi2Error;
    instance->state.phase = PHASE_CONTINUOUS;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint;
    ModelInstance *instance = enter(c, "fmi2CompletedIntegratorStep", PHASE_CONTINUOUS);
    if (instance == NULL) return fmi2Error;
    if (null_argument(instance, "fmi2CompletedIntegratorStep", enterEventMode, "enterEventMode") ||
        null_argument(instance, "fmi2CompletedIntegratorStep", terminateSimulation, "terminateSimulation"))
        return fmi2Error;
    *enterEventMode = model_step_event_needed(&instance->state.data) ? fmi2True : fmi2False;
    *terminateSimulation = model_step_terminate_needed(instance) ? fmi2True : fmi2False;
    return fmi2OK;
}

/* Default for models that never ask to terminate after a step (a model's own definition wins). */
__attribute__((weak)) int model_step_terminate_needed(const ModelInstance *instance) {
    (void)instance;
    return 0;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    ModelInstance *instance = enter(c, "fmi2SetTime", PHASE_EVENT | PHASE_CONTINUOUS);
    if (instance == NULL) return fmi2Error;
    if (!isfinite(time)) {
        fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "fmi2SetTime: time %g is not finite", time);
        return fmi2Error;
    }
    instance->state.time_s = time;
    return fmi2OK;
}

static int check_length(ModelInstance *instance, const char *function, const char *argument, size_t given,
                        size_t expected) {
    if (given == expected) return 0;
    fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: %s = %zu, but %s has %zu", function, argument, given,
            MODEL_IDENTIFIER, expected);
    return 1;
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    const char *function = "fmi2SetContinuousStates";
    ModelInstance *instance = enter(c, function, PHASE_CONTINUOUS);
    if (instance == NULL) return fmi2Error;
    if (check_length(instance, function, "nx", nx, MODEL_N_STATES)) return fmi2Error;
    if (nx == 0) return fmi2OK;
    if (null_argument(instance, function, x, "x")) return fmi2Error;
    for (size_t i = 0; i < nx; ++i) {
        if (!isfinite(x[i])) {
            const VarInfo *state = NULL;
            for (size_t k = 0; k < model_n_variables; ++k)
                if (model_variables[k].kind == VAR_STATE && model_variables[k].index == model_state_index[i])
                    state = &model_variables[k];
            fmu_log(instance, fmi2Error, LOG_STATUS_ERROR, "%s: state %zu (\"%s\") = %g is not a finite number",
                    function, i, state != NULL ? state->name : "?", x[i]);
            return fmi2Error;
        }
    }
    for (size_t i = 0; i < nx; ++i) instance->state.data.real[model_state_index[i]] = x[i];
    return fmi2OK;
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    const char *function = "fmi2GetDerivatives";
    ModelInstance *instance = enter(c, function, AFTER_INSTANTIATION);
    if (instance == NULL) return fmi2Error;
    if (check_length(instance, function, "nx", nx, MODEL_N_STATES)) return fmi2Error;
    if (nx == 0) return fmi2OK;
    if (null_argument(instance, function, derivatives, "derivatives")) return fmi2Error;
    model_calculate(&instance->state.data);
    for (size_t i = 0; i < nx; ++i) derivatives[i] = instance->state.data.real[model_derivative_index[i]];
    return fmi2OK;
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    const char *function = "fmi2GetEventIndicators";
    ModelInstance *instance = enter(c, function, AFTER_INSTANTIATION);
    if (instance == NULL) return fmi2Error;
    if (check_length(instance, function, "ni", ni, MODEL_N_EVENT_INDICATORS)) return fmi2Error;
    if (ni == 0) return fmi2OK;
    if (null_argument(instance, function, eventIndicators, "eventIndicators")) return fmi2Error;
    model_calculate(&instance->state.data);
    model_event_indicators(&instance->state.data, eventIndicators);
    return fmi2OK;
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    const char *function = "fmi2GetContinuousStates";
    ModelInstance *instance = enter(c, function, AFTER_INSTANTIATION);
    if (instance == NULL) return fmi2Error;
    if (check_length(instance, function, "nx", nx, MODEL_N_STATES)) return fmi2Error;
    if (nx == 0) return fmi2OK;
    if (null_argument(instance, function, x, "x")) return fmi2Error;
    for (size_t i = 0; i < nx; ++i) x[i] = instance->state.data.real[model_state_index[i]];
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    const char *function = "fmi2GetNominalsOfContinuousStates";
    ModelInstance *instance = enter(c, function, ALL_PHASES);
    if (instance == NULL) return fmi2Error;
    if (check_length(instance, function, "nx", nx, MODEL_N_STATES)) return fmi2Error;
    if (nx == 0) return fmi2OK;
    if (null_argument(instance, function, x_nominal, "x_nominal")) return fmi2Error;
    for (size_t i = 0; i < nx; ++i) x_nominal[i] = model_state_nominal[i];
    return fmi2OK;
}

/* ------------------------------------------------------------------------ Co-Simulation (not supported) */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return co_simulation_only(c, "fmi2SetRealInputDerivatives");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return co_simulation_only(c, "fmi2GetRealOutputDerivatives");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    (void)currentCommunicationPoint; (void)communicationStepSize; (void)noSetFMUStatePriorToCurrentPoint;
    return co_simulation_only(c, "fmi2DoStep");
}

fmi2Status fmi2CancelStep(fmi2Component c) { return co_simulation_only(c, "fmi2CancelStep"); }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)s; (void)value;
    return co_simulation_only(c, "fmi2GetStatus");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    (void)s; (void)value;
    return co_simulation_only(c, "fmi2GetRealStatus");
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s; (void)value;
    return co_simulation_only(c, "fmi2GetIntegerStatus");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    (void)s; (void)value;
    return co_simulation_only(c, "fmi2GetBooleanStatus");
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s; (void)value;
    return co_simulation_only(c, "fmi2GetStringStatus");
}
