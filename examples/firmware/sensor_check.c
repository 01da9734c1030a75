/*
 * sensor_check.c - the power-up step of a player with absolute joint sensors (the UCB): read
 * each joint's sensor, turn it into counts with dsl_sensor.h, and the steps to the rest pose.
 * Built for the host with a printer's dsl_config.h; the readings come from the command line:
 *
 *     sensor_check R1 R2 R3     prints: "<joint> <reading> <counts> <steps to rest>" per joint
 */
#include <stdio.h>
#include <stdlib.h>

#include DSL_CONFIG
#include "dsl_sensor.h"

int main(int argc, char **argv)
{
    static const int32_t rest[DSL_CFG_JOINTS] = DSL_CFG_REST_COUNTS;
    int j;
    if (argc != DSL_CFG_JOINTS + 1) {
        fprintf(stderr, "usage: %s one reading per joint (%d)\n", argv[0], DSL_CFG_JOINTS);
        return 2;
    }
    for (j = 0; j < DSL_CFG_JOINTS; j++) {
        int32_t reading = (int32_t)atol(argv[j + 1]), c = dsl_sensor_to_counts((uint8_t)j, reading);
        printf("%d %ld %ld %ld\n", j, (long)reading, (long)c, (long)(rest[j] - c));
    }
    return 0;
}
