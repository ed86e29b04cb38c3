/* Quadrotor FMU: FMI 3.0 Co-Simulation glue over the FMI 2.0 one.
 *
 * The FMI 3.0 build (`python -m fmus.build --fmi 3`) compiles model.c and fmi2.c with
 * FMI2_FUNCTION_PREFIX=Quadrotor2_, so the FMI 2.0 functions become internal (hidden) names,
 * and this file maps each FMI 3.0 call onto them: one state machine, one set of checks and
 * messages, one model. What FMI 3.0 adds that this FMU does not use (event mode, clocks,
 * other variable types, Model Exchange in 3.0, scheduled execution) is refused with a log
 * message naming the call.
 */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>

#include "config.h"
#include "fmi3Functions.h"

typedef struct {
    fmi2Component inner;               /* the FMI 2.0 instance (fmi2.c) */
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log;        /* may be NULL */
    char name[128];
} Instance3;

/* The FMI 2.0 logger of the inner instance: formats and hands the text to FMI 3.0's. */
static void forward(fmi2ComponentEnvironment env, fmi2String instanceName, fmi2Status status,
                    fmi2String category, fmi2String message, ...) {
    const Instance3 *w = (const Instance3 *)env;
    char buf[512];
    va_list ap;
    (void)instanceName;
    if (w == NULL || w->log == NULL) return;
    va_start(ap, message);
    vsnprintf(buf, sizeof(buf), message, ap);
    va_end(ap);
    w->log(w->env, (fmi3Status)status, category, buf);
}

static fmi3Status refuse(fmi3Instance instance, const char *what) {
    const Instance3 *w = (const Instance3 *)instance;
    if (w != NULL && w->log != NULL) w->log(w->env, fmi3Error, "logStatusError", what);
    return fmi3Error;
}

#define INNER(instance) (((Instance3 *)(instance))->inner)
#define CHECK_INSTANCE(instance) if ((instance) == NULL) return fmi3Error;

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    CHECK_INSTANCE(instance)
    return (fmi3Status)fmi2SetDebugLogging(INNER(instance), loggingOn ? fmi2True : fmi2False,
                                           nCategories, categories);
}

fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate) {
    fmi2CallbackFunctions cb = {0};
    Instance3 *w;
    (void)earlyReturnAllowed; (void)requiredIntermediateVariables; (void)intermediateUpdate;
    w = (Instance3 *)calloc(1, sizeof(Instance3));
    if (w == NULL) return NULL;
    w->env = instanceEnvironment;
    w->log = logMessage;
    if (eventModeUsed || nRequiredIntermediateVariables > 0) {
        refuse(w, eventModeUsed ? "fmi3InstantiateCoSimulation: this FMU has no event mode "
                                  "(hasEventMode=false)"
                                : "fmi3InstantiateCoSimulation: no intermediate variables");
        free(w);
        return NULL;
    }
    cb.logger = forward;
    cb.componentEnvironment = w;
    w->inner = fmi2Instantiate(instanceName, fmi2CoSimulation, instantiationToken, resourcePath,
                               &cb, visible ? fmi2True : fmi2False,
                               loggingOn ? fmi2True : fmi2False);
    if (w->inner == NULL) {
        free(w);
        return NULL;
    }
    return w;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible;
    (void)loggingOn;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateModelExchange: the FMI 3.0 build is Co-Simulation only "
                   "(Model Exchange: the FMI 2.0 build)");
    return NULL;
}

fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
    fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible;
    (void)loggingOn; (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateScheduledExecution: Co-Simulation only");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) {
    if (instance == NULL) return;
    fmi2FreeInstance(INNER(instance));
    free(instance);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    fmi2Status s;
    CHECK_INSTANCE(instance)
    s = fmi2SetupExperiment(INNER(instance), toleranceDefined ? fmi2True : fmi2False, tolerance,
                            startTime, stopTimeDefined ? fmi2True : fmi2False, stopTime);
    if (s != fmi2OK) return (fmi3Status)s;
    return (fmi3Status)fmi2EnterInitializationMode(INNER(instance));
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    CHECK_INSTANCE(instance)
    return (fmi3Status)fmi2ExitInitializationMode(INNER(instance));
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    CHECK_INSTANCE(instance)
    return (fmi3Status)fmi2Terminate(INNER(instance));
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    CHECK_INSTANCE(instance)
    return (fmi3Status)fmi2Reset(INNER(instance));
}

/* ---- get / set: Float64 and Boolean; every other type has no variable here ------------- */

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          fmi3Float64 values[], size_t nValues) {
    CHECK_INSTANCE(instance)
    if (nValues != nvr) return refuse(instance, "fmi3GetFloat64: nValues != nValueReferences "
                                                "(all variables are scalars)");
    return (fmi3Status)fmi2GetReal(INNER(instance), vr, nvr, values);
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Float64 values[], size_t nValues) {
    CHECK_INSTANCE(instance)
    if (nValues != nvr) return refuse(instance, "fmi3SetFloat64: nValues != nValueReferences "
                                                "(all variables are scalars)");
    return (fmi3Status)fmi2SetReal(INNER(instance), vr, nvr, values);
}

fmi3Status fmi3GetBoolean(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          fmi3Boolean values[], size_t nValues) {
    size_t i;
    CHECK_INSTANCE(instance)
    if (nValues != nvr || (nvr > 0 && (vr == NULL || values == NULL)))
        return refuse(instance, "fmi3GetBoolean: bad arguments");
    for (i = 0; i < nvr; i++) {
        fmi2Boolean b = fmi2False;
        fmi2Status s = fmi2GetBoolean(INNER(instance), &vr[i], 1, &b);
        if (s != fmi2OK) return (fmi3Status)s;
        values[i] = b != fmi2False;
    }
    return fmi3OK;
}

fmi3Status fmi3SetBoolean(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Boolean values[], size_t nValues) {
    size_t i;
    CHECK_INSTANCE(instance)
    if (nValues != nvr || (nvr > 0 && (vr == NULL || values == NULL)))
        return refuse(instance, "fmi3SetBoolean: bad arguments");
    for (i = 0; i < nvr; i++) {
        const fmi2Boolean b = values[i] ? fmi2True : fmi2False;
        fmi2Status s = fmi2SetBoolean(INNER(instance), &vr[i], 1, &b);
        if (s != fmi2OK) return (fmi3Status)s;
    }
    return fmi3OK;
}

/* Types without variables: an empty call is fine, any value reference is unknown. */
#define NO_VARIABLES(F, T, CONST)                                                              \
    fmi3Status F(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,             \
                 CONST T values[], size_t nValues) {                                           \
        (void)vr; (void)values; (void)nValues;                                                 \
        CHECK_INSTANCE(instance)                                                               \
        return nvr == 0 ? fmi3OK : refuse(instance, #F ": unknown value reference (this FMU "  \
                                                       "has Float64 and Boolean variables)");  \
    }
NO_VARIABLES(fmi3GetFloat32, fmi3Float32, )
NO_VARIABLES(fmi3GetInt8, fmi3Int8, )
NO_VARIABLES(fmi3GetUInt8, fmi3UInt8, )
NO_VARIABLES(fmi3GetInt16, fmi3Int16, )
NO_VARIABLES(fmi3GetUInt16, fmi3UInt16, )
NO_VARIABLES(fmi3GetInt32, fmi3Int32, )
NO_VARIABLES(fmi3GetUInt32, fmi3UInt32, )
NO_VARIABLES(fmi3GetInt64, fmi3Int64, )
NO_VARIABLES(fmi3GetUInt64, fmi3UInt64, )
NO_VARIABLES(fmi3GetString, fmi3String, )
NO_VARIABLES(fmi3SetFloat32, fmi3Float32, const)
NO_VARIABLES(fmi3SetInt8, fmi3Int8, const)
NO_VARIABLES(fmi3SetUInt8, fmi3UInt8, const)
NO_VARIABLES(fmi3SetInt16, fmi3Int16, const)
NO_VARIABLES(fmi3SetUInt16, fmi3UInt16, const)
NO_VARIABLES(fmi3SetInt32, fmi3Int32, const)
NO_VARIABLES(fmi3SetUInt32, fmi3UInt32, const)
NO_VARIABLES(fmi3SetInt64, fmi3Int64, const)
NO_VARIABLES(fmi3SetUInt64, fmi3UInt64, const)
NO_VARIABLES(fmi3SetString, fmi3String, const)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues) {
    (void)vr; (void)valueSizes; (void)values; (void)nValues;
    CHECK_INSTANCE(instance)
    return nvr == 0 ? fmi3OK : refuse(instance, "fmi3GetBinary: unknown value reference");
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         const size_t valueSizes[], const fmi3Binary values[], size_t nValues) {
    (void)vr; (void)valueSizes; (void)values; (void)nValues;
    CHECK_INSTANCE(instance)
    return nvr == 0 ? fmi3OK : refuse(instance, "fmi3SetBinary: unknown value reference");
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        fmi3Clock values[]) {
    (void)vr; (void)values;
    CHECK_INSTANCE(instance)
    return nvr == 0 ? fmi3OK : refuse(instance, "fmi3GetClock: this FMU has no clocks");
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Clock values[]) {
    (void)vr; (void)values;
    CHECK_INSTANCE(instance)
    return nvr == 0 ? fmi3OK : refuse(instance, "fmi3SetClock: this FMU has no clocks");
}

/* ---- FMU state: the FMI 2.0 snapshot as it is ------------------------------------------ */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *state) {
    CHECK_INSTANCE(instance)
    return (fmi3Status)fmi2GetFMUstate(INNER(instance), state);
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState state) {
    CHECK_INSTANCE(instance)
    return (fmi3Status)fmi2SetFMUstate(INNER(instance), state);
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *state) {
    CHECK_INSTANCE(instance)
    return (fmi3Status)fmi2FreeFMUstate(INNER(instance), state);
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState state, size_t *size) {
    CHECK_INSTANCE(instance)
    return (fmi3Status)fmi2SerializedFMUstateSize(INNER(instance), state, size);
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState state, fmi3Byte out[],
                                 size_t size) {
    CHECK_INSTANCE(instance)
    return (fmi3Status)fmi2SerializeFMUstate(INNER(instance), state, out, size);
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte in[], size_t size,
                                   fmi3FMUState *state) {
    CHECK_INSTANCE(instance)
    return (fmi3Status)fmi2DeSerializeFMUstate(INNER(instance), in, size, state);
}

/* ---- Co-Simulation ---------------------------------------------------------------------- */

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    fmi2Status s;
    CHECK_INSTANCE(instance)
    if (eventHandlingNeeded) *eventHandlingNeeded = false;
    if (terminateSimulation) *terminateSimulation = false;
    if (earlyReturn) *earlyReturn = false;
    s = fmi2DoStep(INNER(instance), currentCommunicationPoint, communicationStepSize,
                   noSetFMUStatePriorToCurrentPoint ? fmi2True : fmi2False);
    if (lastSuccessfulTime) {
        fmi2Real t = currentCommunicationPoint;
        fmi2GetRealStatus(INNER(instance), fmi2LastSuccessfulTime, &t);
        *lastSuccessfulTime = t;
    }
    return (fmi3Status)s;
}

/* ---- what this FMU does not provide ----------------------------------------------------- */

#define REFUSE0(F, WHY)                                                                        \
    fmi3Status F(fmi3Instance instance) { CHECK_INSTANCE(instance) return refuse(instance, #F ": " WHY); }
REFUSE0(fmi3EnterEventMode, "this FMU has no event mode")
REFUSE0(fmi3EnterStepMode, "this FMU has no event mode")
REFUSE0(fmi3EnterConfigurationMode, "this FMU has no structural parameters")
REFUSE0(fmi3ExitConfigurationMode, "this FMU has no structural parameters")
REFUSE0(fmi3EvaluateDiscreteStates, "Co-Simulation only")
REFUSE0(fmi3EnterContinuousTimeMode, "Co-Simulation only")

#define NOT_PROVIDED(F, ...)                                                                   \
    fmi3Status F(fmi3Instance instance, __VA_ARGS__) {                                         \
        CHECK_INSTANCE(instance)                                                               \
        return refuse(instance, #F ": not provided by this FMU");                             \
    }
#define U __attribute__((unused))
NOT_PROVIDED(fmi3GetNumberOfVariableDependencies, U fmi3ValueReference a, U size_t *b)
NOT_PROVIDED(fmi3GetVariableDependencies, U fmi3ValueReference a, U size_t b[],
             U fmi3ValueReference c[], U size_t d[], U fmi3DependencyKind e[], U size_t f)
NOT_PROVIDED(fmi3GetDirectionalDerivative, U const fmi3ValueReference a[], U size_t b,
             U const fmi3ValueReference c[], U size_t d, U const fmi3Float64 e[], U size_t f,
             U fmi3Float64 g[], U size_t h)
NOT_PROVIDED(fmi3GetAdjointDerivative, U const fmi3ValueReference a[], U size_t b,
             U const fmi3ValueReference c[], U size_t d, U const fmi3Float64 e[], U size_t f,
             U fmi3Float64 g[], U size_t h)
NOT_PROVIDED(fmi3GetIntervalDecimal, U const fmi3ValueReference a[], U size_t b,
             U fmi3Float64 c[], U fmi3IntervalQualifier d[])
NOT_PROVIDED(fmi3GetIntervalFraction, U const fmi3ValueReference a[], U size_t b,
             U fmi3UInt64 c[], U fmi3UInt64 d[], U fmi3IntervalQualifier e[])
NOT_PROVIDED(fmi3GetShiftDecimal, U const fmi3ValueReference a[], U size_t b, U fmi3Float64 c[])
NOT_PROVIDED(fmi3GetShiftFraction, U const fmi3ValueReference a[], U size_t b, U fmi3UInt64 c[],
             U fmi3UInt64 d[])
NOT_PROVIDED(fmi3SetIntervalDecimal, U const fmi3ValueReference a[], U size_t b,
             U const fmi3Float64 c[])
NOT_PROVIDED(fmi3SetIntervalFraction, U const fmi3ValueReference a[], U size_t b,
             U const fmi3UInt64 c[], U const fmi3UInt64 d[])
NOT_PROVIDED(fmi3SetShiftDecimal, U const fmi3ValueReference a[], U size_t b,
             U const fmi3Float64 c[])
NOT_PROVIDED(fmi3SetShiftFraction, U const fmi3ValueReference a[], U size_t b,
             U const fmi3UInt64 c[], U const fmi3UInt64 d[])
NOT_PROVIDED(fmi3UpdateDiscreteStates, U fmi3Boolean *a, U fmi3Boolean *b, U fmi3Boolean *c,
             U fmi3Boolean *d, U fmi3Boolean *e, U fmi3Float64 *f)
NOT_PROVIDED(fmi3CompletedIntegratorStep, U fmi3Boolean a, U fmi3Boolean *b, U fmi3Boolean *c)
NOT_PROVIDED(fmi3SetTime, U fmi3Float64 a)
NOT_PROVIDED(fmi3SetContinuousStates, U const fmi3Float64 a[], U size_t b)
NOT_PROVIDED(fmi3GetContinuousStateDerivatives, U fmi3Float64 a[], U size_t b)
NOT_PROVIDED(fmi3GetEventIndicators, U fmi3Float64 a[], U size_t b)
NOT_PROVIDED(fmi3GetContinuousStates, U fmi3Float64 a[], U size_t b)
NOT_PROVIDED(fmi3GetNominalsOfContinuousStates, U fmi3Float64 a[], U size_t b)
NOT_PROVIDED(fmi3GetNumberOfEventIndicators, U size_t *a)
NOT_PROVIDED(fmi3GetNumberOfContinuousStates, U size_t *a)
NOT_PROVIDED(fmi3GetOutputDerivatives, U const fmi3ValueReference a[], U size_t b,
             U const fmi3Int32 c[], U fmi3Float64 d[], U size_t e)
NOT_PROVIDED(fmi3ActivateModelPartition, U fmi3ValueReference a, U fmi3Float64 b)
