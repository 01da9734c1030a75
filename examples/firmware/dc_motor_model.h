/*
 * dc_motor_model.h - a simulated DC gear motor with a quadrature encoder, in place of the UADY's
 * motors where there are none (dc_pid_player.c on the PC, m0_pid_player.c in QEMU).
 *
 * Stated, plausible for a 12 V 34:1 gear motor with an 11-pulse Hall encoder, since the UADY
 * document gives no motor data: 12 V supply, armature 4 ohm, torque and back-EMF constant
 * 0.038 N m/A (3000 rpm at 12 V no load), rotor plus reflected arm inertia 4e-6 kg m^2 at the
 * motor, viscous 5e-6 N m s, Coulomb friction 0.003 N m, gravity of a 100 g arm at 75 mm
 * (0.0022 N m at the motor at horizontal), 34:1 gearbox, 44 counts per motor turn (1496 per
 * output turn), integrated at 20 kHz.
 */
#ifndef DC_MOTOR_MODEL_H
#define DC_MOTOR_MODEL_H

#include <math.h>
#include <stdint.h>

#define SUBSTEPS 20

typedef struct {
    double theta, omega; /* motor shaft: rad, rad/s */
} motor;

static const double V_SUPPLY = 12.0, R = 4.0, K = 0.038, J = 4e-6, B = 5e-6, TC = 0.003, GRAV = 0.0022, GEAR = 34.0;
static const double COUNTS_PER_RAD = 44.0 / 6.283185307179586; /* at the motor shaft: 44 x 34 = 1496 per output turn */

static int32_t encoder(const motor *m) { return (int32_t)floor(m->theta * COUNTS_PER_RAD); }

/* Advance one control period of dt seconds at a duty of -255..255. */
static void motor_run(motor *m, int32_t duty, double dt)
{
    int k;
    double h = dt / SUBSTEPS, v = V_SUPPLY * duty / 255.0;
    for (k = 0; k < SUBSTEPS; k++) {
        double i = (v - K * m->omega) / R;
        double torque = K * i - B * m->omega - GRAV * cos(m->theta / GEAR);
        if (fabs(m->omega) > 1e-3) torque -= TC * (m->omega > 0 ? 1.0 : -1.0);
        else if (fabs(torque) < TC) torque = 0.0, m->omega = 0.0; /* stiction holds it */
        else torque -= TC * (torque > 0 ? 1.0 : -1.0);
        m->omega += h * torque / J;
        m->theta += h * m->omega;
    }
}

#endif
