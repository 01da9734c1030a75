/*
 * dc_pid_player.c - the UADY delta's DC gear motors under dc_pid.h, following a deltaslice
 * stream; built for the host with a simulated motor per joint in place of the PSoC's PWM and
 * quadrature decoder:
 *
 *     dc_pid_player STREAM.dsl            one line per sample: i sp1 pos1 duty1 sp2 pos2 duty2 ...
 *     dc_pid_player --step COUNTS --ms N  a setpoint step on one joint (saturation, windup)
 *
 * The simulated motor is dc_motor_model.h's (the Cortex-M0 build, m0_pid_player.c, runs the same
 * one); the PID runs once per sample (1 kHz).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "dc_motor_model.h"
#include "dc_pid.h"
#include "dsl_file.h"
#include "dsl_player.h"

#define JOINTS_MAX 4

static int step_response(int32_t step, int ms)
{
    dc_pid c;
    motor m = {0.0, 0.0};
    dc_pid_gains g = DC_PID_UADY_GAINS;
    int t;
    dc_pid_init(&c, g);
    for (t = 0; t < ms; t++) {
        int32_t pos = encoder(&m), duty = dc_pid_step(&c, t ? step : 0, pos);
        printf("%d %ld %ld %ld\n", t, (long)(t ? step : 0), (long)pos, (long)duty);
        motor_run(&m, duty, 1e-3);
    }
    return 0;
}

static dsl_player player;

int main(int argc, char **argv)
{
    static dsl_file input;
    dc_pid pid[JOINTS_MAX];
    motor mot[JOINTS_MAX];
    int32_t counts[DSL_MAX_CHANNELS], origin[JOINTS_MAX];
    dc_pid_gains g = DC_PID_UADY_GAINS;
    int started = 0, j, joints = 0;
    double dt = 1e-3;

    if (argc == 5 && !strcmp(argv[1], "--step") && !strcmp(argv[3], "--ms"))
        return step_response((int32_t)atol(argv[2]), atoi(argv[4]));
    if (argc != 2) {
        fprintf(stderr, "usage: %s STREAM.dsl | --step COUNTS --ms N\n", argv[0]);
        return 2;
    }
    if (dsl_file_start(&player, &input, argv[1], 4096) != 0) return 2;
    for (;;) {
        int r, status;
        while ((r = dsl_next(&player, counts)) == DSL_SAMPLE || r == DSL_EVENT) {
            if (r == DSL_EVENT) continue; /* no heaters on this machine's joints */
            if (!started) {
                /* the machine starts at the stream's first sample (its rest pose): the encoder
                   counters are zeroed there and the setpoints taken relative to it */
                joints = player.n_channels - 1 > JOINTS_MAX ? JOINTS_MAX : player.n_channels - 1;
                dt = 1e-3 * 1000000.0 / player.rate_mhz;
                for (j = 0; j < joints; j++) {
                    origin[j] = counts[j];
                    mot[j].theta = mot[j].omega = 0.0;
                    dc_pid_init(&pid[j], g);
                }
                started = 1;
            }
            printf("%lu", (unsigned long)(player.sample_index - 1));
            for (j = 0; j < joints; j++) {
                int32_t sp = counts[j] - origin[j];
                int32_t pos = (int32_t)floor(mot[j].theta * COUNTS_PER_RAD);
                int32_t duty = dc_pid_step(&pid[j], sp, pos);
                printf(" %ld %ld %ld", (long)sp, (long)pos, (long)duty);
                motor_run(&mot[j], duty, dt);
            }
            putchar('\n');
        }
        status = dsl_file_continue(&player, &input, r, argv[1]);
        if (status == 0) break;
        if (status != DSL_FILE_MORE) return status;
    }
    dsl_file_close(&input);
    return 0;
}
