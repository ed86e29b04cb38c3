/* Quadrotor FMU: the physics (start values, derivatives, outputs, RK4 substep).
 *
 * Frames: world NED, body FRD. Quaternion q = [w, x, y, z] rotates body -> world.
 * Rotors (PX4 quad-X), positions in body axes with a = arm_length*sqrt(2)/2:
 *   1 front-right (+a, +a) CCW   2 rear-left (-a, -a) CCW
 *   3 front-left  (+a, -a) CW    4 rear-right (-a, +a) CW      (spin viewed from above)
 * Equations and their derivation: readme.md next to this file.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "config.h"

#define S(vr) ((vr) - VR_FIRST_STATE) /* index into the state vector */
#define P(m, name) ((m)->r[vr_##name])

/* gain of the constraint term that pulls |q| back to 1 between renormalisations, 1/s */
#define QUAT_NORM_GAIN 1.0

static const char *const NAMES[N_VR] = {
    "time",
    "u1", "u2", "u3", "u4", "wind_n", "wind_e", "wind_d",
    "x", "y", "z", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "p", "q", "r",
    "omega1", "omega2", "omega3", "omega4",
    "ax", "ay", "az", "on_ground",
    "der(x)", "der(y)", "der(z)", "der(vx)", "der(vy)", "der(vz)",
    "der(qw)", "der(qx)", "der(qy)", "der(qz)", "der(p)", "der(q)", "der(r)",
    "der(omega1)", "der(omega2)", "der(omega3)", "der(omega4)",
    "mass", "Ixx", "Iyy", "Izz", "arm_length", "k_thrust", "k_torque", "motor_tau",
    "omega_max", "drag_xy", "drag_z", "drag_rot", "g",
    "contact_omega", "contact_zeta", "contact_friction", "contact_omega_att",
    "x0", "y0", "z0", "yaw0", "omega0", "substep",
};

const char *model_variable_name(unsigned int vr) {
    return vr < N_VR ? NAMES[vr] : "?";
}

/* Start values: Parrot Mambo (cosim/vehicles.py MAMBO; sources in readme.md). */
void model_set_start_values(ModelData *m) {
    memset(m, 0, sizeof(*m));
    P(m, mass) = 0.063;
    P(m, Ixx) = 5.82857e-5;
    P(m, Iyy) = 7.16914e-5;
    P(m, Izz) = 1.0e-4;
    P(m, arm_length) = 0.0624;
    P(m, k_thrust) = 4.72e-8;
    P(m, k_torque) = 1.14e-10;
    P(m, motor_tau) = 0.02;
    P(m, omega_max) = 2631.0;
    P(m, drag_xy) = 0.013;
    P(m, drag_z) = 0.0146;
    P(m, drag_rot) = 1.0e-6;
    P(m, g) = 9.81;
    P(m, contact_omega) = 200.0;
    P(m, contact_zeta) = 2.0;
    P(m, contact_friction) = 50.0;
    P(m, contact_omega_att) = 50.0;
    P(m, x0) = 0.0;
    P(m, y0) = 0.0;
    P(m, z0) = 0.0;
    P(m, yaw0) = 0.0;
    P(m, omega0) = 0.0;
    P(m, substep) = 0.001;
    model_apply_initial_state(m);
}

/* States from the initial-condition parameters: at rest, level, heading yaw0. A vehicle
 * placed on (or into) the floor, z0 >= 0, starts at the static contact equilibrium
 * z = g/contact_omega^2 (0.25 mm with the defaults), so it rests from t = 0 without a
 * settling transient (and an ODE solver does not start exactly on the contact switch). */
void model_apply_initial_state(ModelData *m) {
    double *s = &m->r[VR_FIRST_STATE];
    int i;
    for (i = 0; i < N_STATES; i++) s[i] = 0.0;
    s[S(vr_x)] = P(m, x0);
    s[S(vr_y)] = P(m, y0);
    s[S(vr_z)] = P(m, z0) >= 0.0
                     ? P(m, g) / (P(m, contact_omega) * P(m, contact_omega))
                     : P(m, z0);
    s[S(vr_qw)] = cos(0.5 * P(m, yaw0));
    s[S(vr_qz)] = sin(0.5 * P(m, yaw0));
    for (i = 0; i < 4; i++) s[S(vr_omega1) + i] = P(m, omega0);
    m->r[vr_on_ground] = model_on_ground(m) ? 1.0 : 0.0;
    /* inverses used by the derivatives (parameters only change before initialisation) */
    m->inv_mass = 1.0 / P(m, mass);
    m->inv_I[0] = 1.0 / P(m, Ixx);
    m->inv_I[1] = 1.0 / P(m, Iyy);
    m->inv_I[2] = 1.0 / P(m, Izz);
    m->inv_motor_tau = 1.0 / P(m, motor_tau);
    m->outputsValid = 0;
}

static double clamp01(double u) {
    /* NaN is rejected by fmi2SetReal; +-inf clamp like any other out-of-range value */
    return u < 0.0 ? 0.0 : (u > 1.0 ? 1.0 : u);
}

/* State derivative ds = f(s, inputs, parameters). If f_B is not NULL it receives the
 * specific force in body axes (what an ideal accelerometer at the CG reads), m/s^2. */
void model_derivatives(const ModelData *m, const double *s, double *ds, double *f_B) {
    const double g = P(m, g), inv_mass = m->inv_mass;
    const double Ixx = P(m, Ixx), Iyy = P(m, Iyy), Izz = P(m, Izz);
    const double a = P(m, arm_length) * 0.70710678118654752440;
    const double kT = P(m, k_thrust), kQ = P(m, k_torque);

    const double vx = s[S(vr_vx)], vy = s[S(vr_vy)], vz = s[S(vr_vz)];
    double qw = s[S(vr_qw)], qx = s[S(vr_qx)], qy = s[S(vr_qy)], qz = s[S(vr_qz)];
    const double p = s[S(vr_p)], q = s[S(vr_q)], r = s[S(vr_r)];
    const double *w = &s[S(vr_omega1)];

    /* rotation body->world from the normalised quaternion */
    const double qq = qw * qw + qx * qx + qy * qy + qz * qz;
    const double inv = 1.0 / sqrt(qq);
    const double nw = qw * inv, nx = qx * inv, ny = qy * inv, nz = qz * inv;
    const double R00 = 1.0 - 2.0 * (ny * ny + nz * nz), R01 = 2.0 * (nx * ny - nw * nz),
                 R02 = 2.0 * (nx * nz + nw * ny);
    const double R10 = 2.0 * (nx * ny + nw * nz), R11 = 1.0 - 2.0 * (nx * nx + nz * nz),
                 R12 = 2.0 * (ny * nz - nw * nx);
    const double R20 = 2.0 * (nx * nz - nw * ny), R21 = 2.0 * (ny * nz + nw * nx),
                 R22 = 1.0 - 2.0 * (nx * nx + ny * ny);

    /* rotor thrusts (along -z_B) and reaction torques */
    const double T1 = kT * w[0] * w[0], T2 = kT * w[1] * w[1];
    const double T3 = kT * w[2] * w[2], T4 = kT * w[3] * w[3];
    const double Ttot = T1 + T2 + T3 + T4;
    double tau_x = a * (-T1 + T2 + T3 - T4);
    double tau_y = a * (T1 - T2 + T3 - T4);
    double tau_z = kQ * (w[0] * w[0] + w[1] * w[1] - w[2] * w[2] - w[3] * w[3]);

    /* airframe drag against the air, body axes: F = -D R_BW (v_W - wind_W) */
    const double ax_W = vx - m->r[vr_wind_n], ay_W = vy - m->r[vr_wind_e],
                 az_W = vz - m->r[vr_wind_d];
    const double va_x = R00 * ax_W + R10 * ay_W + R20 * az_W;
    const double va_y = R01 * ax_W + R11 * ay_W + R21 * az_W;
    const double va_z = R02 * ax_W + R12 * ay_W + R22 * az_W;
    const double FBx = -P(m, drag_xy) * va_x;
    const double FBy = -P(m, drag_xy) * va_y;
    const double FBz = -P(m, drag_z) * va_z - Ttot;

    /* ground contact (floor z = 0, NED): spring-damper normal force, viscous friction,
     * levelling torque and rate damping, all scaled by act = Fn/(m g) in [0, 1].
     * Computed per unit mass (accelerations), so the static equilibrium is exact. */
    double ac_n = 0.0, ac_e = 0.0, ac_d = 0.0;
    const double pen = s[S(vr_z)];
    if (pen > 0.0) {
        const double wn = P(m, contact_omega), zeta = P(m, contact_zeta);
        const double an = wn * wn * pen + 2.0 * zeta * wn * vz; /* normal force / mass */
        if (an > 0.0) {
            double act = an / g;
            const double wa = P(m, contact_omega_att);
            /* world "down" in body axes = third row of R_WB */
            const double dx = R20, dy = R21;
            if (act > 1.0) act = 1.0;
            ac_d = -an;
            ac_n = -P(m, contact_friction) * act * vx;
            ac_e = -P(m, contact_friction) * act * vy;
            tau_x += Ixx * act * (-wa * wa * dy - 2.0 * zeta * wa * p);
            tau_y += Iyy * act * (wa * wa * dx - 2.0 * zeta * wa * q);
            tau_z += Izz * act * (-2.0 * zeta * wa * r);
        }
    }

    /* rotational damping */
    tau_x -= P(m, drag_rot) * p;
    tau_y -= P(m, drag_rot) * q;
    tau_z -= P(m, drag_rot) * r;

    /* kinematics */
    ds[S(vr_x)] = vx;
    ds[S(vr_y)] = vy;
    ds[S(vr_z)] = vz;

    /* translational dynamics, world axes */
    ds[S(vr_vx)] = (R00 * FBx + R01 * FBy + R02 * FBz) * inv_mass + ac_n;
    ds[S(vr_vy)] = (R10 * FBx + R11 * FBy + R12 * FBz) * inv_mass + ac_e;
    ds[S(vr_vz)] = (R20 * FBx + R21 * FBy + R22 * FBz) * inv_mass + ac_d + g;

    /* attitude kinematics q_dot = 1/2 q (x) [0, w_B], plus a term that keeps |q| = 1 */
    {
        const double k = QUAT_NORM_GAIN * (1.0 - qq);
        ds[S(vr_qw)] = 0.5 * (-qx * p - qy * q - qz * r) + k * qw;
        ds[S(vr_qx)] = 0.5 * (qw * p + qy * r - qz * q) + k * qx;
        ds[S(vr_qy)] = 0.5 * (qw * q + qz * p - qx * r) + k * qy;
        ds[S(vr_qz)] = 0.5 * (qw * r + qx * q - qy * p) + k * qz;
    }

    /* Euler's equations, diagonal inertia: I w_dot = tau - w x (I w) */
    ds[S(vr_p)] = (tau_x - (Izz - Iyy) * q * r) * m->inv_I[0];
    ds[S(vr_q)] = (tau_y - (Ixx - Izz) * r * p) * m->inv_I[1];
    ds[S(vr_r)] = (tau_z - (Iyy - Ixx) * p * q) * m->inv_I[2];

    /* first-order motor lag towards the clamped command */
    {
        const double wmax = P(m, omega_max), inv_tau = m->inv_motor_tau;
        int i;
        for (i = 0; i < 4; i++) {
            const double wcmd = clamp01(m->r[vr_u1 + i]) * wmax;
            ds[S(vr_omega1) + i] = (wcmd - w[i]) * inv_tau;
        }
    }

    if (f_B) {
        /* specific force = (all forces except gravity) / m, in body axes */
        f_B[0] = FBx * inv_mass + R00 * ac_n + R10 * ac_e + R20 * ac_d;
        f_B[1] = FBy * inv_mass + R01 * ac_n + R11 * ac_e + R21 * ac_d;
        f_B[2] = FBz * inv_mass + R02 * ac_n + R12 * ac_e + R22 * ac_d;
    }
}

int model_on_ground(const ModelData *m) {
    const double z = m->r[vr_z];
    return z > 0.0 || (z == 0.0 && m->r[vr_vz] >= 0.0);
}

/* Algebraic outputs and derivative variables from the current states and inputs. */
void model_update_outputs(ModelData *m) {
    double f_B[3];
    model_derivatives(m, &m->r[VR_FIRST_STATE], &m->r[vr_der_x], f_B);
    m->r[vr_ax] = f_B[0];
    m->r[vr_ay] = f_B[1];
    m->r[vr_az] = f_B[2];
    m->outputsValid = 1;
}

/* One classical Runge-Kutta step of length dt with inputs held; then renormalise the
 * quaternion and keep rotor speeds in [0, omega_max]. */
void model_rk4_step(ModelData *m, double dt) {
    double *s = &m->r[VR_FIRST_STATE];
    double k1[N_STATES], k2[N_STATES], k3[N_STATES], k4[N_STATES], tmp[N_STATES];
    const double h2 = 0.5 * dt, h6 = dt / 6.0;
    int i;

    model_derivatives(m, s, k1, NULL);
    for (i = 0; i < N_STATES; i++) tmp[i] = s[i] + h2 * k1[i];
    model_derivatives(m, tmp, k2, NULL);
    for (i = 0; i < N_STATES; i++) tmp[i] = s[i] + h2 * k2[i];
    model_derivatives(m, tmp, k3, NULL);
    for (i = 0; i < N_STATES; i++) tmp[i] = s[i] + dt * k3[i];
    model_derivatives(m, tmp, k4, NULL);
    for (i = 0; i < N_STATES; i++) s[i] += h6 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);

    {
        double *qv = &s[S(vr_qw)];
        const double n = sqrt(qv[0] * qv[0] + qv[1] * qv[1] + qv[2] * qv[2] + qv[3] * qv[3]);
        for (i = 0; i < 4; i++) qv[i] /= n;
    }
    for (i = 0; i < 4; i++) {
        double *wi = &s[S(vr_omega1) + i];
        if (*wi < 0.0) *wi = 0.0;
        if (*wi > P(m, omega_max)) *wi = P(m, omega_max);
    }
    m->outputsValid = 0;
}

/* Range checks for parameters and inputs. The bounds keep every value where the physics and
 * doStep's work stay meaningful: the smallest substep bounds the work per step (with
 * fmi2DoStep's MAX_SUBSTEPS), wind and start positions stay physical. */
#define SUBSTEP_MIN 1e-6  /* s */
#define WIND_MAX 100.0    /* m/s, any wind component */
#define POS0_MAX 1e6      /* m, any start coordinate */
const char *model_check_value(unsigned int vr, double v, char *why, size_t n) {
    const char *name = model_variable_name(vr);
    if (vr >= vr_u1 && vr <= vr_u4) {
        if (isnan(v)) {
            snprintf(why, n, "input '%s' must be a number, got NaN", name);
            return why;
        }
        return NULL; /* out-of-range commands are clamped to [0, 1] */
    }
    if (!isfinite(v)) {
        snprintf(why, n, "%s '%s' must be finite, got %g",
                 vr <= VR_LAST_INPUT ? "input" : "parameter", name, v);
        return why;
    }
    switch (vr) {
    case vr_mass: case vr_Ixx: case vr_Iyy: case vr_Izz: case vr_arm_length:
    case vr_k_thrust: case vr_motor_tau: case vr_omega_max: case vr_g:
    case vr_contact_omega:
        if (!(v > 0.0)) {
            snprintf(why, n, "parameter '%s' must be > 0, got %g", name, v);
            return why;
        }
        break;
    case vr_k_torque: case vr_drag_xy: case vr_drag_z: case vr_drag_rot:
    case vr_contact_zeta: case vr_contact_friction: case vr_contact_omega_att:
    case vr_omega0:
        if (!(v >= 0.0)) {
            snprintf(why, n, "parameter '%s' must be >= 0, got %g", name, v);
            return why;
        }
        break;
    case vr_substep:
        if (!(v >= SUBSTEP_MIN && v <= 0.001)) {
            snprintf(why, n, "parameter 'substep' must be in [%g, 0.001] s, got %g", SUBSTEP_MIN,
                     v);
            return why;
        }
        break;
    case vr_wind_n: case vr_wind_e: case vr_wind_d:
        if (!(fabs(v) <= WIND_MAX)) {
            snprintf(why, n, "input '%s' must be within +-%g m/s, got %g", name, WIND_MAX, v);
            return why;
        }
        break;
    case vr_x0: case vr_y0: case vr_z0:
        if (!(fabs(v) <= POS0_MAX)) {
            snprintf(why, n, "parameter '%s' must be within +-%g m, got %g", name, POS0_MAX, v);
            return why;
        }
        break;
    default:
        break;
    }
    return NULL;
}
