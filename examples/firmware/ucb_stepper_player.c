/*
 * ucb_stepper_player.c - the UCB delta (ESP32, steppers, one potentiometer per joint), built for
 * the host: the power-up step and the playback of a stream as step pulses, with the portable
 * cores the ESP32 firmware uses (dsl_player.h, dsl_sensor.h, dsl_stepper.h) and config/delta_ucb.h.
 *
 *     ucb_stepper_player STREAM.dsl R1 R2 R3     the pots' raw readings at power-up
 *
 * 1. Power-up: each joint's reading becomes its count (dsl_sensor.h: the printer file's
 *    sensor_table); the steppers then step from there to the rest pose (DSL_CFG_REST_COUNTS) along
 *    a trapezoid of each joint's own limits (DSL_CFG_JOINT_VMAX, DSL_CFG_JOINT_AMAX), a setpoint
 *    per sample period as the stream's.
 * 2. Playback: every sample's count differences as step pulses spread over its period
 *    (dsl_stepper.h), as on the Mega; the extruder (the tool channel) starts where the stream does.
 *
 * The step and dir "pins" are counted here: each pulse moves its axis one count in the direction
 * set at the sample start. Output, all positions counted from the pulses:
 *
 *     # sensor <joint> <reading> <counts> <steps to rest>   one per joint
 *     # move <pos1> <pos2> <pos3>                            the power-up move, each period
 *     # home <periods> <pos1> <pos2> <pos3>                  where the power-up move ended
 *     <i> <pos1> <pos2> <pos3> <pos4>                        at the end of each sample's period
 *     # overruns <n>                                         samples whose steps did not fit
 *
 * On the ESP32: a hardware timer at DSL_SUBTICKS x the sample rate (32 kHz) runs the tick,
 * GPIOs for step/dir (the pins are in docs/bring-up.md), the ADC reads the pots once at power-up.
 */
#include <stdio.h>
#include <stdlib.h>

#include DSL_CONFIG
#include "dsl_file.h"
#include "dsl_player.h"
#include "dsl_sensor.h"
#include "dsl_stepper.h"

#define AXES DSL_STEP_AXES

static dsl_player player;
static dsl_stepper stepper;
static int32_t pins_pos[AXES]; /* counted from the step pulses */

/* One sample period: take the target counts, then the DSL_SUBTICKS - 1 step slots. */
static void period(const int32_t *target, uint8_t axes)
{
    uint8_t dirs = dsl_stepper_sample(&stepper, target, axes), t, a;
    for (t = 1; t < DSL_SUBTICKS; t++) {
        uint8_t m = dsl_stepper_tick(&stepper, axes);
        for (a = 0; a < axes; a++)
            if (m & (1u << a)) pins_pos[a] += dirs & (1u << a) ? 1 : -1;
    }
}

/* The power-up move's next setpoint of one joint: a trapezoid in Q16 counts per period (v, a:
   speed and its change per period, the limits' own), braking once the distance left is what
   braking from this speed takes. Integer arithmetic, once per period, only at power-up. */
typedef struct {
    int64_t left, v, vmax, a; /* Q16 */
} ramp;

static int64_t ramp_step(ramp *r)
{
    int64_t d;
    if (r->left <= 0) return 0;
    if (r->v * r->v / (2 * r->a) >= r->left) r->v = r->v - r->a > r->a ? r->v - r->a : r->a;
    else if (r->v < r->vmax) r->v = r->v + r->a < r->vmax ? r->v + r->a : r->vmax;
    d = r->v < r->left ? r->v : r->left;
    r->left -= d;
    return d;
}

int main(int argc, char **argv)
{
    static const int32_t rest[DSL_CFG_JOINTS] = DSL_CFG_REST_COUNTS;
    static dsl_file input;
    int32_t counts[DSL_MAX_CHANNELS], start[AXES] = {0}, target[AXES] = {0};
    uint8_t axes = 0, a;
    int started = 0, j;
    unsigned long periods = 0;

    if (argc != DSL_CFG_JOINTS + 2) {
        fprintf(stderr, "usage: %s STREAM.dsl and one pot reading per joint (%d)\n", argv[0], DSL_CFG_JOINTS);
        return 2;
    }
    if (dsl_file_start(&player, &input, argv[1], 64) != 0) return 2;
    for (;;) {
        int r, status;
        while ((r = dsl_next(&player, counts)) == DSL_SAMPLE || r == DSL_EVENT) {
            if (r == DSL_EVENT) continue; /* the UCB's hot end has its own controller */
            if (!started) {
                if (player.fingerprint != DSL_CFG_FINGERPRINT) {
                    fprintf(stderr, "error: %s: stream made for another printer (fingerprint)\n", argv[1]);
                    return 1;
                }
                axes = (uint8_t)(player.n_channels < AXES ? player.n_channels : AXES);
                /* power-up: where the pots say the joints are; the extruder where the stream starts */
                for (a = 0; a < axes; a++) start[a] = target[a] = counts[a];
                for (j = 0; j < DSL_CFG_JOINTS && j < axes; j++) {
                    int32_t reading = (int32_t)atol(argv[2 + j]);
                    start[j] = dsl_sensor_to_counts((uint8_t)j, reading);
                    target[j] = rest[j];
                    printf("# sensor %d %ld %ld %ld\n", j, (long)reading, (long)start[j], (long)(rest[j] - start[j]));
                }
                for (a = 0; a < axes; a++) pins_pos[a] = start[a];
                dsl_stepper_init(&stepper, start, axes);
                {   /* to the rest pose along each joint's trapezoid */
                    static const int32_t vmax[DSL_CFG_JOINTS] = DSL_CFG_JOINT_VMAX, amax[DSL_CFG_JOINTS] = DSL_CFG_JOINT_AMAX;
                    int64_t rate = (int64_t)(player.rate_mhz / 1000u), done[AXES] = {0};
                    int32_t set[AXES];
                    ramp rp[DSL_CFG_JOINTS];
                    uint8_t moving = 1;
                    for (j = 0; j < DSL_CFG_JOINTS && j < axes; j++) {
                        int32_t d = target[j] - start[j];
                        rp[j].left = (int64_t)(d < 0 ? -d : d) << 16;
                        rp[j].v = 0;
                        rp[j].vmax = ((int64_t)vmax[j] << 16) / rate;
                        rp[j].a = ((int64_t)amax[j] << 16) / (rate * rate);
                        if (rp[j].a < 1) rp[j].a = 1;
                    }
                    for (a = 0; a < axes; a++) set[a] = start[a];
                    while (moving) {
                        moving = 0;
                        for (j = 0; j < DSL_CFG_JOINTS && j < axes; j++) {
                            done[j] += ramp_step(&rp[j]);
                            moving |= rp[j].left > 0;
                            set[j] = start[j] + (int32_t)((target[j] < start[j] ? -done[j] : done[j]) / 65536);
                        }
                        period(set, axes);
                        periods++;
                        printf("# move");
                        for (j = 0; j < DSL_CFG_JOINTS; j++) printf(" %ld", (long)pins_pos[j]);
                        putchar('\n');
                    }
                }
                printf("# home %lu", periods);
                for (j = 0; j < DSL_CFG_JOINTS; j++) printf(" %ld", (long)pins_pos[j]);
                putchar('\n');
                started = 1;
            }
            period(counts, axes);
            printf("%lu", (unsigned long)(player.sample_index - 1));
            for (a = 0; a < axes; a++) printf(" %ld", (long)pins_pos[a]);
            putchar('\n');
        }
        status = dsl_file_continue(&player, &input, r, argv[1]);
        if (status == 0) break;
        if (status != DSL_FILE_MORE) return status;
    }
    printf("# overruns %lu\n", (unsigned long)stepper.overruns);
    dsl_file_close(&input);
    return 0;
}
