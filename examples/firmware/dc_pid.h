/*
 * dc_pid.h - position control of a DC gear motor with a quadrature encoder: a PID in integer
 * arithmetic (an 8- or 32-bit MCU without an FPU runs it at 1 kHz), portable C99.
 *
 *   u = Kp e + I + Kd (-d position) + Kff (d setpoint),   e = setpoint - position (counts)
 *
 * Gains are Q8 fixed point (256 = 1.0 output unit per count); the output is a PWM duty in
 * -out_max..out_max. Derivative on the measurement (a setpoint step does not kick the motor),
 * velocity feed-forward from the setpoint's change per sample (the stream's samples are already
 * a smooth, limited trajectory, so most of the drive comes from it and the loop only corrects),
 * anti-windup by conditional integration: the integral grows only while the output is not
 * saturated in the direction it would push, and is clamped to +-i_max.
 */
#ifndef DC_PID_H
#define DC_PID_H

#include <stdint.h>

typedef struct {
    int32_t kp, ki, kd, kff; /* Q8: output units per count (kp, ki per sample, kd, kff per count/sample) */
    int32_t out_max;         /* PWM full scale, e.g. 255 */
    int32_t i_max;           /* integral clamp, output units x 256 */
} dc_pid_gains;

/* The UADY's motors (12 V, 34:1, 1496 counts per output turn), tuned on the simulated motor of
   dc_pid_player.c at 1 kHz along a compiled part (the move from rest, the layer, the park):
   Kp 16 duty per count (full duty at a 16-count error), Ki 0.5 duty per count per sample
   (clamped at 128 duty), Kd 50 duty per count of motion per sample, and a feed-forward of 60 duty
   per count per sample of setpoint motion (half of what the unloaded motor needs: 255 duty turns
   it 2.1 counts a sample; the loop does the rest). Following error: 2 counts at most (the gains
   before, 12 / 0.25 / 40 / 30, reached 4 counts where the move from rest breaks away). */
#define DC_PID_UADY_GAINS {16 * 256, 128, 50 * 256, 60 * 256, 255, 128 * 256}

typedef struct {
    dc_pid_gains g;
    int32_t integral;  /* output units x 256 */
    int32_t last_pos, last_sp;
    uint8_t started;
} dc_pid;

static void dc_pid_init(dc_pid *c, dc_pid_gains g)
{
    c->g = g;
    c->integral = 0;
    c->last_pos = c->last_sp = 0;
    c->started = 0;
}

/* One control period: setpoint and measured position in counts -> duty in -out_max..out_max. */
static int32_t dc_pid_step(dc_pid *c, int32_t setpoint, int32_t position)
{
    int32_t e = setpoint - position, u, out;
    int32_t dpos, dsp;
    if (!c->started) {
        c->last_pos = position;
        c->last_sp = setpoint;
        c->started = 1;
    }
    dpos = position - c->last_pos;
    dsp = setpoint - c->last_sp;
    c->last_pos = position;
    c->last_sp = setpoint;
    u = c->g.kp * e + c->integral - c->g.kd * dpos + c->g.kff * dsp; /* x 256 */
    out = u / 256;
    if (out > c->g.out_max) out = c->g.out_max;
    if (out < -c->g.out_max) out = -c->g.out_max;
    /* conditional integration: not while saturated in the direction the error pushes */
    if (!((out == c->g.out_max && e > 0) || (out == -c->g.out_max && e < 0))) {
        c->integral += c->g.ki * e;
        if (c->integral > c->g.i_max) c->integral = c->g.i_max;
        if (c->integral < -c->g.i_max) c->integral = -c->g.i_max;
    }
    return out;
}

#endif
