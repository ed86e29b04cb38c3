/* Quadrotor FMU: identifier, value references and the model data record.
 *
 * Every Real variable lives in ModelData.r[], indexed by its value reference, so
 * fmi2GetReal/fmi2SetReal are array look-ups and an FMU state is one memcpy.
 * The value references here must match modelDescription.xml (tests/test_fmu.py checks it).
 */
#ifndef QUADROTOR_CONFIG_H
#define QUADROTOR_CONFIG_H

#include "fmi2Functions.h"

#define MODEL_IDENTIFIER_STRING "Quadrotor"
#define MODEL_GUID "{5e0c4a8e-7c1b-4f0e-9a51-2b8f3c6d9e10}"

#define N_STATES 17
#define N_EVENT_INDICATORS 1

typedef enum {
    vr_time = 0,
    /* inputs */
    vr_u1, vr_u2, vr_u3, vr_u4,                 /* 1..4   normalised motor commands, 1 */
    vr_wind_n, vr_wind_e, vr_wind_d,            /* 5..7   wind velocity in NED, m/s */
    /* continuous states (also outputs), in state-vector order */
    vr_x, vr_y, vr_z,                           /* 8..10  position NED, m */
    vr_vx, vr_vy, vr_vz,                        /* 11..13 velocity NED, m/s */
    vr_qw, vr_qx, vr_qy, vr_qz,                 /* 14..17 attitude quaternion body->world */
    vr_p, vr_q, vr_r,                           /* 18..20 body rates FRD, rad/s */
    vr_omega1, vr_omega2, vr_omega3, vr_omega4, /* 21..24 rotor speeds, rad/s */
    /* algebraic outputs */
    vr_ax, vr_ay, vr_az,                        /* 25..27 specific force, body, m/s^2 */
    vr_on_ground,                               /* 28     Boolean output (stored as 0/1) */
    /* derivatives of the states (local) */
    vr_der_x,                                   /* 29..45 */
    vr_der_omega4 = vr_der_x + N_STATES - 1,
    /* parameters */
    vr_mass,                                    /* 46 */
    vr_Ixx, vr_Iyy, vr_Izz,
    vr_arm_length,
    vr_k_thrust, vr_k_torque,
    vr_motor_tau, vr_omega_max,
    vr_drag_xy, vr_drag_z, vr_drag_rot,
    vr_g,
    vr_contact_omega, vr_contact_zeta, vr_contact_friction, vr_contact_omega_att,
    vr_x0, vr_y0, vr_z0, vr_yaw0, vr_omega0,
    vr_substep,                                 /* 68 */
    N_VR
} ValueReference;

#define VR_FIRST_STATE vr_x
#define VR_FIRST_INPUT vr_u1
#define VR_LAST_INPUT vr_wind_d
#define VR_FIRST_PARAM vr_mass
#define VR_LAST_PARAM vr_substep

/* Everything that makes up the state of one instance: plain old data, no pointers,
 * so fmi2GetFMUstate/SetFMUstate and (de)serialisation are a memcpy. */
typedef struct {
    double r[N_VR];        /* all Real variables by value reference (on_ground as 0/1) */
    double time;           /* s, current time */
    double inv_mass, inv_I[3], inv_motor_tau; /* 1/kg, 1/(kg m^2), 1/s: from the parameters */
    int outputsValid;      /* algebraic outputs (ax, ay, az) are up to date */
} ModelData;

/* model.c */
void model_set_start_values(ModelData *m);
void model_apply_initial_state(ModelData *m);
void model_derivatives(const ModelData *m, const double *s, double *ds, double *f_B);
void model_update_outputs(ModelData *m);
void model_rk4_step(ModelData *m, double dt);
int model_on_ground(const ModelData *m);
const char *model_variable_name(unsigned int vr);
/* Checks a value for a parameter or input; returns NULL if fine, else writes a reason into
 * `why` (size n) and returns it. */
const char *model_check_value(unsigned int vr, double value, char *why, size_t n);

#endif
