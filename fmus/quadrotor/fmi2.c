/* Quadrotor FMU: FMI 2.0 glue (Co-Simulation and Model Exchange in one binary).
 *
 * State machine, argument checks with specific log messages, get/set, FMU states,
 * Co-Simulation doStep (fixed-step RK4 substeps) and the Model Exchange interface.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "config.h"

/* Flush denormals to zero while integrating. Decaying quantities (rotor speeds after the
 * motors stop, velocities under floor friction) otherwise sink into subnormal numbers, which
 * makes every arithmetic operation on them ~5x slower. FTZ/DAZ only changes results below
 * 2.2e-308, deterministically; the caller's MXCSR is restored on return. */
#if defined(__SSE2__) || defined(__x86_64__)
#include <xmmintrin.h>
#define FTZ_BEGIN const unsigned int mxcsr_saved = _mm_getcsr(); _mm_setcsr(mxcsr_saved | 0x8040u);
#define FTZ_END _mm_setcsr(mxcsr_saved);
#else
#define FTZ_BEGIN
#define FTZ_END
#endif

/* FMI states as bits, so that "allowed in" is one mask test */
enum {
    ST_INSTANTIATED = 1 << 0,
    ST_INIT = 1 << 1,
    ST_STEP_COMPLETE = 1 << 2,
    ST_STEP_FAILED = 1 << 3,
    ST_EVENT = 1 << 4,
    ST_CONT = 1 << 5,
    ST_TERMINATED = 1 << 6,
    ST_ERROR = 1 << 7,
    ST_FATAL = 1 << 8
};

#define ST_ANY (ST_INSTANTIATED | ST_INIT | ST_STEP_COMPLETE | ST_STEP_FAILED | ST_EVENT | \
                ST_CONT | ST_TERMINATED | ST_ERROR)
#define ST_GET (ST_INIT | ST_STEP_COMPLETE | ST_STEP_FAILED | ST_EVENT | ST_CONT | \
                ST_TERMINATED | ST_ERROR)
#define ST_SET (ST_INSTANTIATED | ST_INIT | ST_STEP_COMPLETE | ST_EVENT | ST_CONT)

typedef struct {
    ModelData md;
    fmi2Type type;
    int state;
    fmi2Boolean loggingOn;
    char instanceName[128];
    fmi2CallbackLogger logger;
    fmi2ComponentEnvironment env;
    double startTime;
    char msg[512];
} Instance;

#define STATE_MAGIC 0x51524f54u /* "QROT" */

/* What fmi2GetFMUstate captures (and what is serialised, byte for byte). */
typedef struct {
    unsigned int magic;
    unsigned int size;
    int state;
    int pad;
    double startTime;
    ModelData md;
} Snapshot;

static const char *state_name(int st) {
    switch (st) {
    case ST_INSTANTIATED: return "Instantiated";
    case ST_INIT: return "InitializationMode";
    case ST_STEP_COMPLETE: return "StepComplete";
    case ST_STEP_FAILED: return "StepFailed";
    case ST_EVENT: return "EventMode";
    case ST_CONT: return "ContinuousTimeMode";
    case ST_TERMINATED: return "Terminated";
    case ST_ERROR: return "Error";
    case ST_FATAL: return "Fatal";
    default: return "?";
    }
}

static void log_msg(Instance *c, fmi2Status status, const char *category, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(c->msg, sizeof(c->msg), fmt, ap);
    va_end(ap);
    if (c->logger && (status >= fmi2Error || c->loggingOn)) {
        c->logger(c->env, c->instanceName, status, category, "%s", c->msg);
    }
}

/* Log an error and put the instance into the Error state. */
static fmi2Status fail(Instance *c, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(c->msg, sizeof(c->msg), fmt, ap);
    va_end(ap);
    if (c->logger) c->logger(c->env, c->instanceName, fmi2Error, "logStatusError", "%s", c->msg);
    c->state = ST_ERROR;
    return fmi2Error;
}

/* Check that `f` may be called now; logs "f: not allowed in state X" otherwise. */
static int bad_state(Instance *c, const char *f, int allowed) {
    if (c == NULL) return 1;
    if (c->state & allowed) return 0;
    /* a call in the wrong state is reported, the instance keeps its state */
    log_msg(c, fmi2Error, "logStatusError", "%s: not allowed in state %s", f, state_name(c->state));
    return 1;
}

static int bad_type(Instance *c, const char *f, fmi2Type t) {
    if (c->type == t) return 0;
    log_msg(c, fmi2Error, "logStatusError", "%s: only for %s instances", f,
            t == fmi2CoSimulation ? "Co-Simulation" : "Model Exchange");
    return 1;
}

#define CHECK(f, allowed)                                      \
    Instance *inst = (Instance *)c;                            \
    if (inst == NULL) return fmi2Error;                        \
    if (bad_state(inst, f, allowed)) return fmi2Error;

#define NULLCHECK(f, ptr, n)                                                        \
    if ((n) > 0 && (ptr) == NULL) return fail(inst, "%s: argument '%s' is NULL", f, #ptr);

/* ------------------------------------------------------------------------------------- */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    CHECK("fmi2SetDebugLogging", ST_ANY)
    (void)nCategories;
    (void)categories;
    inst->loggingOn = loggingOn;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    Instance *c;
    (void)fmuResourceLocation;
    (void)visible;
    if (functions == NULL || functions->logger == NULL) return NULL;
    if (instanceName == NULL || instanceName[0] == '\0') {
        functions->logger(functions->componentEnvironment, "?", fmi2Error, "logStatusError",
                          "%s", "fmi2Instantiate: missing instance name");
        return NULL;
    }
    if (fmuGUID == NULL || strcmp(fmuGUID, MODEL_GUID) != 0) {
        functions->logger(functions->componentEnvironment, instanceName, fmi2Error,
                          "logStatusError", "fmi2Instantiate: wrong GUID %s, expected %s",
                          fmuGUID ? fmuGUID : "(null)", MODEL_GUID);
        return NULL;
    }
    if (fmuType != fmi2CoSimulation && fmuType != fmi2ModelExchange) {
        functions->logger(functions->componentEnvironment, instanceName, fmi2Error,
                          "logStatusError", "fmi2Instantiate: unknown fmuType %d",
                          (int)fmuType);
        return NULL;
    }
    c = (Instance *)calloc(1, sizeof(Instance));
    if (c == NULL) return NULL;
    strncpy(c->instanceName, instanceName, sizeof(c->instanceName) - 1);
    c->type = fmuType;
    c->logger = functions->logger;
    c->env = functions->componentEnvironment;
    c->loggingOn = loggingOn;
    c->state = ST_INSTANTIATED;
    model_set_start_values(&c->md);
    return c;
}

void fmi2FreeInstance(fmi2Component c) {
    if (c) free(c);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined,
                               fmi2Real stopTime) {
    CHECK("fmi2SetupExperiment", ST_INSTANTIATED)
    (void)toleranceDefined;
    (void)tolerance;
    if (!isfinite(startTime))
        return fail(inst, "fmi2SetupExperiment: startTime must be finite, got %g", startTime);
    if (stopTimeDefined && !(stopTime >= startTime))
        return fail(inst, "fmi2SetupExperiment: stopTime %g is before startTime %g", stopTime,
                    startTime);
    inst->startTime = startTime;
    inst->md.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    CHECK("fmi2EnterInitializationMode", ST_INSTANTIATED)
    model_apply_initial_state(&inst->md);
    inst->md.time = inst->startTime;
    inst->state = ST_INIT;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    CHECK("fmi2ExitInitializationMode", ST_INIT)
    if (inst->md.r[vr_omega0] > inst->md.r[vr_omega_max])
        return fail(inst,
                    "fmi2ExitInitializationMode: parameter 'omega0' (%g rad/s) must not exceed "
                    "'omega_max' (%g rad/s)",
                    inst->md.r[vr_omega0], inst->md.r[vr_omega_max]);
    model_apply_initial_state(&inst->md);
    inst->state = inst->type == fmi2CoSimulation ? ST_STEP_COMPLETE : ST_EVENT;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    CHECK("fmi2Terminate", ST_STEP_COMPLETE | ST_STEP_FAILED | ST_EVENT | ST_CONT)
    inst->state = ST_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    CHECK("fmi2Reset", ST_ANY)
    model_set_start_values(&inst->md);
    inst->startTime = 0.0;
    inst->state = ST_INSTANTIATED;
    return fmi2OK;
}

/* ---- get / set ---------------------------------------------------------------------- */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    size_t i;
    CHECK("fmi2GetReal", ST_GET)
    NULLCHECK("fmi2GetReal", vr, nvr)
    NULLCHECK("fmi2GetReal", value, nvr)
    if (!inst->md.outputsValid) {
        FTZ_BEGIN
        model_update_outputs(&inst->md);
        FTZ_END
    }
    for (i = 0; i < nvr; i++) {
        const fmi2ValueReference v = vr[i];
        if (v >= N_VR || v == vr_on_ground)
            return fail(inst, "fmi2GetReal: unknown value reference %u", (unsigned)v);
        value[i] = v == vr_time ? inst->md.time : inst->md.r[v];
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    size_t i;
    CHECK("fmi2GetBoolean", ST_GET)
    NULLCHECK("fmi2GetBoolean", vr, nvr)
    NULLCHECK("fmi2GetBoolean", value, nvr)
    for (i = 0; i < nvr; i++) {
        if (vr[i] != vr_on_ground)
            return fail(inst, "fmi2GetBoolean: unknown value reference %u", (unsigned)vr[i]);
        value[i] = inst->md.r[vr_on_ground] != 0.0 ? fmi2True : fmi2False;
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    CHECK("fmi2GetInteger", ST_GET)
    (void)value;
    if (nvr > 0) return fail(inst, "fmi2GetInteger: unknown value reference %u", vr ? vr[0] : 0);
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    CHECK("fmi2GetString", ST_GET)
    (void)value;
    if (nvr > 0) return fail(inst, "fmi2GetString: unknown value reference %u", vr ? vr[0] : 0);
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    size_t i;
    int params_changed = 0;
    char why[256];
    CHECK("fmi2SetReal", ST_SET)
    NULLCHECK("fmi2SetReal", vr, nvr)
    NULLCHECK("fmi2SetReal", value, nvr)
    for (i = 0; i < nvr; i++) {
        const fmi2ValueReference v = vr[i];
        const char *reason;
        if (v >= N_VR) return fail(inst, "fmi2SetReal: unknown value reference %u", (unsigned)v);
        if (v >= VR_FIRST_PARAM && v <= VR_LAST_PARAM) {
            if (!(inst->state & (ST_INSTANTIATED | ST_INIT)))
                return fail(inst,
                            "fmi2SetReal: parameter '%s' is fixed and cannot be set in state %s",
                            model_variable_name(v), state_name(inst->state));
            params_changed = 1;
        } else if (!(v >= VR_FIRST_INPUT && v <= VR_LAST_INPUT)) {
            return fail(inst, "fmi2SetReal: variable '%s' is not an input or parameter",
                        model_variable_name(v));
        }
        reason = model_check_value(v, value[i], why, sizeof(why));
        if (reason) return fail(inst, "fmi2SetReal: %s", reason);
        inst->md.r[v] = value[i];
    }
    if (params_changed) model_apply_initial_state(&inst->md);
    inst->md.outputsValid = 0;
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    CHECK("fmi2SetInteger", ST_SET)
    (void)value;
    if (nvr > 0) return fail(inst, "fmi2SetInteger: unknown value reference %u", vr ? vr[0] : 0);
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    CHECK("fmi2SetBoolean", ST_SET)
    (void)value;
    if (nvr > 0) {
        if (vr && vr[0] == vr_on_ground)
            return fail(inst, "fmi2SetBoolean: variable 'on_ground' is an output");
        return fail(inst, "fmi2SetBoolean: unknown value reference %u", vr ? vr[0] : 0);
    }
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    CHECK("fmi2SetString", ST_SET)
    (void)value;
    if (nvr > 0) return fail(inst, "fmi2SetString: unknown value reference %u", vr ? vr[0] : 0);
    return fmi2OK;
}

/* ---- FMU state ---------------------------------------------------------------------- */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    Snapshot *s;
    CHECK("fmi2GetFMUstate", ST_ANY)
    if (FMUstate == NULL) return fail(inst, "fmi2GetFMUstate: argument 'FMUstate' is NULL");
    s = (Snapshot *)*FMUstate;
    if (s == NULL) {
        s = (Snapshot *)calloc(1, sizeof(Snapshot));
        if (s == NULL) return fail(inst, "fmi2GetFMUstate: out of memory");
        *FMUstate = s;
    } else if (s->magic != STATE_MAGIC) {
        return fail(inst, "fmi2GetFMUstate: *FMUstate is not a Quadrotor FMU state");
    }
    s->magic = STATE_MAGIC;
    s->size = (unsigned int)sizeof(Snapshot);
    s->state = inst->state;
    s->startTime = inst->startTime;
    memcpy(&s->md, &inst->md, sizeof(ModelData));
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    const Snapshot *s = (const Snapshot *)FMUstate;
    CHECK("fmi2SetFMUstate", ST_ANY)
    if (s == NULL || s->magic != STATE_MAGIC || s->size != sizeof(Snapshot))
        return fail(inst, "fmi2SetFMUstate: not a Quadrotor FMU state");
    memcpy(&inst->md, &s->md, sizeof(ModelData));
    inst->state = s->state;
    inst->startTime = s->startTime;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    CHECK("fmi2FreeFMUstate", ST_ANY)
    if (FMUstate == NULL) return fmi2OK;
    free(*FMUstate);
    *FMUstate = NULL;
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    CHECK("fmi2SerializedFMUstateSize", ST_ANY)
    (void)FMUstate;
    if (size == NULL) return fail(inst, "fmi2SerializedFMUstateSize: argument 'size' is NULL");
    *size = sizeof(Snapshot);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size) {
    const Snapshot *s = (const Snapshot *)FMUstate;
    CHECK("fmi2SerializeFMUstate", ST_ANY)
    if (s == NULL || s->magic != STATE_MAGIC)
        return fail(inst, "fmi2SerializeFMUstate: not a Quadrotor FMU state");
    if (serializedState == NULL || size < sizeof(Snapshot))
        return fail(inst, "fmi2SerializeFMUstate: buffer of %lu bytes is too small (need %lu)",
                    (unsigned long)size, (unsigned long)sizeof(Snapshot));
    memcpy(serializedState, s, sizeof(Snapshot));
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    Snapshot tmp;
    Snapshot *s;
    CHECK("fmi2DeSerializeFMUstate", ST_ANY)
    if (serializedState == NULL || FMUstate == NULL)
        return fail(inst, "fmi2DeSerializeFMUstate: NULL argument");
    if (size != sizeof(Snapshot))
        return fail(inst, "fmi2DeSerializeFMUstate: %lu bytes is not a Quadrotor state "
                          "(expected %lu)", (unsigned long)size, (unsigned long)sizeof(Snapshot));
    memcpy(&tmp, serializedState, sizeof(Snapshot));
    if (tmp.magic != STATE_MAGIC || tmp.size != sizeof(Snapshot))
        return fail(inst, "fmi2DeSerializeFMUstate: not a Quadrotor FMU state (bad header)");
    s = (Snapshot *)*FMUstate;
    if (s == NULL) {
        s = (Snapshot *)calloc(1, sizeof(Snapshot));
        if (s == NULL) return fail(inst, "fmi2DeSerializeFMUstate: out of memory");
        *FMUstate = s;
    }
    memcpy(s, &tmp, sizeof(Snapshot));
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    CHECK("fmi2GetDirectionalDerivative", ST_ANY)
    (void)vUnknown_ref; (void)nUnknown; (void)vKnown_ref; (void)nKnown; (void)dvKnown;
    (void)dvUnknown;
    return fail(inst, "fmi2GetDirectionalDerivative: not provided by this FMU");
}

/* ---- Co-Simulation ------------------------------------------------------------------ */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    CHECK("fmi2SetRealInputDerivatives", ST_ANY)
    (void)vr; (void)nvr; (void)order; (void)value;
    return fail(inst, "fmi2SetRealInputDerivatives: inputs are held constant over a step "
                      "(canInterpolateInputs=false)");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    CHECK("fmi2GetRealOutputDerivatives", ST_ANY)
    (void)vr; (void)nvr; (void)order; (void)value;
    return fail(inst, "fmi2GetRealOutputDerivatives: not provided (maxOutputDerivativeOrder=0)");
}

/* Work bound of one doStep: at most this many RK4 substeps (10 s of 1 ms substeps), so a huge
 * communicationStepSize is an error, never a hang. */
#define MAX_SUBSTEPS 10000L

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    ModelData *m;
    double hsub, t0, h;
    long n, i;
    Instance *inst = (Instance *)c;
    if (inst == NULL) return fmi2Error;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (bad_type(inst, "fmi2DoStep", fmi2CoSimulation)) return fmi2Error;
    if (bad_state(inst, "fmi2DoStep", ST_STEP_COMPLETE)) return fmi2Error;
    m = &inst->md;
    t0 = currentCommunicationPoint;
    h = communicationStepSize;
    if (!(h > 0.0) || !isfinite(h))
        return fail(inst, "fmi2DoStep: communicationStepSize must be > 0, got %g", h);
    if (!isfinite(t0) || fabs(t0 - m->time) > 1e-9 * (1.0 + fabs(m->time)))
        return fail(inst, "fmi2DoStep: currentCommunicationPoint %.17g does not match the FMU "
                          "time %.17g", t0, m->time);
    hsub = m->r[vr_substep];
    /* n substeps of hsub; the last one ends exactly at t0 + h (shorter if h/hsub is not
     * an integer). Substep boundaries are t0 + i*hsub, never accumulated. */
    if (h / hsub > (double)MAX_SUBSTEPS)
        return fail(inst, "fmi2DoStep: communicationStepSize %g s needs more than %ld substeps "
                          "of %g s (at most %g s per step)", h, (long)MAX_SUBSTEPS, hsub,
                    (double)MAX_SUBSTEPS * hsub);
    n = (long)ceil(h / hsub * (1.0 - 1e-12));
    if (n < 1) n = 1;
    {
        FTZ_BEGIN
        for (i = 0; i < n; i++) {
            const double ta = (double)i * hsub;
            const double tb = (i == n - 1) ? h : (double)(i + 1) * hsub;
            model_rk4_step(m, tb - ta);
        }
        FTZ_END
    }
    for (i = VR_FIRST_STATE; i < VR_FIRST_STATE + N_STATES; i++) {
        if (!isfinite(m->r[i])) {
            inst->state = ST_STEP_FAILED;
            log_msg(inst, fmi2Error, "logStatusError",
                    "fmi2DoStep: state '%s' is not finite at t = %g", model_variable_name(i),
                    t0 + h);
            return fmi2Error;
        }
    }
    m->time = t0 + h;
    m->r[vr_on_ground] = model_on_ground(m) ? 1.0 : 0.0;
    m->outputsValid = 0;
    return fmi2OK;
}

/* Not part of FMI 2.0: a convenience for the cosim master's per-tick path (cosim/plant.py).
 * fmi2SetReal(inputs) + fmi2DoStep + fmi2GetReal(outputs) + fmi2GetBoolean(flags) in one call,
 * each with exactly its own checks, state changes, log messages and results; stops at the
 * first status that is not fmi2OK and returns it. A ctypes call costs ~1 us from Python, the
 * whole RK4 step ~2 us, so four calls per tick cost more than the model. FMI tools never
 * call it; tests/test_plant.py checks it gives the same bits as the four standard calls. */
FMI2_Export fmi2Status quadrotorSetStepGet(fmi2Component c, const fmi2ValueReference in_vr[],
                                           size_t n_in, const fmi2Real in_val[],
                                           fmi2Real currentCommunicationPoint,
                                           fmi2Real communicationStepSize,
                                           const fmi2ValueReference out_vr[], size_t n_out,
                                           fmi2Real out_val[],
                                           const fmi2ValueReference bool_vr[], size_t n_bool,
                                           fmi2Boolean bool_val[]) {
    fmi2Status s = fmi2SetReal(c, in_vr, n_in, in_val);
    if (s != fmi2OK) return s;
    s = fmi2DoStep(c, currentCommunicationPoint, communicationStepSize, fmi2True);
    if (s != fmi2OK) return s;
    s = fmi2GetReal(c, out_vr, n_out, out_val);
    if (s != fmi2OK) return s;
    return fmi2GetBoolean(c, bool_vr, n_bool, bool_val);
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    CHECK("fmi2CancelStep", ST_ANY)
    return fail(inst, "fmi2CancelStep: doStep is synchronous, nothing to cancel");
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    CHECK("fmi2GetStatus", ST_ANY)
    (void)s; (void)value;
    return fmi2Discard;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    CHECK("fmi2GetRealStatus", ST_ANY)
    if (s == fmi2LastSuccessfulTime && value) {
        *value = inst->md.time;
        return fmi2OK;
    }
    return fmi2Discard;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    CHECK("fmi2GetIntegerStatus", ST_ANY)
    (void)s; (void)value;
    return fmi2Discard;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    CHECK("fmi2GetBooleanStatus", ST_ANY)
    if (s == fmi2Terminated && value) {
        *value = fmi2False;
        return fmi2OK;
    }
    return fmi2Discard;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    CHECK("fmi2GetStringStatus", ST_ANY)
    (void)s; (void)value;
    return fmi2Discard;
}

/* ---- Model Exchange ----------------------------------------------------------------- */

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    CHECK("fmi2EnterEventMode", ST_EVENT | ST_CONT)
    if (bad_type(inst, "fmi2EnterEventMode", fmi2ModelExchange)) return fmi2Error;
    inst->state = ST_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo) {
    CHECK("fmi2NewDiscreteStates", ST_EVENT)
    if (bad_type(inst, "fmi2NewDiscreteStates", fmi2ModelExchange)) return fmi2Error;
    if (eventInfo == NULL) return fail(inst, "fmi2NewDiscreteStates: eventInfo is NULL");
    /* the only discrete variable: on_ground, switched when z crosses the floor */
    inst->md.r[vr_on_ground] = model_on_ground(&inst->md) ? 1.0 : 0.0;
    eventInfo->newDiscreteStatesNeeded = fmi2False;
    eventInfo->terminateSimulation = fmi2False;
    eventInfo->nominalsOfContinuousStatesChanged = fmi2False;
    eventInfo->valuesOfContinuousStatesChanged = fmi2False;
    eventInfo->nextEventTimeDefined = fmi2False;
    eventInfo->nextEventTime = 0.0;
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    CHECK("fmi2EnterContinuousTimeMode", ST_EVENT)
    if (bad_type(inst, "fmi2EnterContinuousTimeMode", fmi2ModelExchange)) return fmi2Error;
    inst->state = ST_CONT;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode,
                                       fmi2Boolean *terminateSimulation) {
    CHECK("fmi2CompletedIntegratorStep", ST_CONT)
    (void)noSetFMUStatePriorToCurrentPoint;
    if (enterEventMode) *enterEventMode = fmi2False;
    if (terminateSimulation) *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    CHECK("fmi2SetTime", ST_EVENT | ST_CONT)
    if (bad_type(inst, "fmi2SetTime", fmi2ModelExchange)) return fmi2Error;
    if (!isfinite(time)) return fail(inst, "fmi2SetTime: time must be finite, got %g", time);
    inst->md.time = time;
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    size_t i;
    CHECK("fmi2SetContinuousStates", ST_CONT)
    if (bad_type(inst, "fmi2SetContinuousStates", fmi2ModelExchange)) return fmi2Error;
    if (nx != N_STATES || x == NULL)
        return fail(inst, "fmi2SetContinuousStates: expected %d states, got %lu", N_STATES,
                    (unsigned long)nx);
    for (i = 0; i < nx; i++) {
        if (!isfinite(x[i]))
            return fail(inst, "fmi2SetContinuousStates: state '%s' is not finite (%g)",
                        model_variable_name(VR_FIRST_STATE + (unsigned)i), x[i]);
    }
    memcpy(&inst->md.r[VR_FIRST_STATE], x, N_STATES * sizeof(double));
    inst->md.outputsValid = 0;
    return fmi2OK;
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    CHECK("fmi2GetDerivatives", ST_INIT | ST_EVENT | ST_CONT | ST_TERMINATED | ST_ERROR)
    if (nx != N_STATES || derivatives == NULL)
        return fail(inst, "fmi2GetDerivatives: expected %d states, got %lu", N_STATES,
                    (unsigned long)nx);
    if (!inst->md.outputsValid) {
        FTZ_BEGIN
        model_update_outputs(&inst->md);
        FTZ_END
    }
    memcpy(derivatives, &inst->md.r[vr_der_x], N_STATES * sizeof(double));
    return fmi2OK;
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    CHECK("fmi2GetEventIndicators", ST_INIT | ST_EVENT | ST_CONT | ST_TERMINATED | ST_ERROR)
    if (ni != N_EVENT_INDICATORS || eventIndicators == NULL)
        return fail(inst, "fmi2GetEventIndicators: expected %d indicator, got %lu",
                    N_EVENT_INDICATORS, (unsigned long)ni);
    eventIndicators[0] = inst->md.r[vr_z]; /* crosses zero at touch-down and lift-off */
    return fmi2OK;
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    CHECK("fmi2GetContinuousStates", ST_INIT | ST_EVENT | ST_CONT | ST_TERMINATED | ST_ERROR)
    if (nx != N_STATES || x == NULL)
        return fail(inst, "fmi2GetContinuousStates: expected %d states, got %lu", N_STATES,
                    (unsigned long)nx);
    memcpy(x, &inst->md.r[VR_FIRST_STATE], N_STATES * sizeof(double));
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    size_t i;
    CHECK("fmi2GetNominalsOfContinuousStates", ST_ANY)
    if (nx != N_STATES || x_nominal == NULL)
        return fail(inst, "fmi2GetNominalsOfContinuousStates: expected %d states, got %lu",
                    N_STATES, (unsigned long)nx);
    for (i = 0; i < nx; i++) x_nominal[i] = 1.0;
    for (i = vr_omega1 - VR_FIRST_STATE; i < N_STATES; i++) x_nominal[i] = inst->md.r[vr_omega_max];
    return fmi2OK;
}
