/*
 * dsl_sensor.h - where a joint is at power-up, from an absolute sensor (the UCB's potentiometers):
 * the printer file's [joints] sensor_table, written into dsl_config.h by `deltaslice
 * firmware-config` as raw readings (ascending) and the joint counts at them, interpolated
 * piecewise-linearly in integers (and extrapolated along the end segments), as
 * Printer.joint_from_sensor does in Python. Portable C99; include after the config header.
 */
#ifndef DSL_SENSOR_H
#define DSL_SENSOR_H

#include <stdint.h>

#if DSL_CFG_SENSOR_POINTS > 1
static const int32_t dsl_sensor_adc[DSL_CFG_JOINTS][DSL_CFG_SENSOR_POINTS] = DSL_CFG_SENSOR_ADC;
static const int32_t dsl_sensor_counts[DSL_CFG_JOINTS][DSL_CFG_SENSOR_POINTS] = DSL_CFG_SENSOR_COUNTS;

/* The joint count of a raw reading of joint j's sensor, rounded to the nearest count. */
static int32_t dsl_sensor_to_counts(uint8_t j, int32_t reading)
{
    uint8_t k = 0;
    int32_t r0, r1, c0, c1, num, den;
    while (k + 2 < DSL_CFG_SENSOR_POINTS && reading > dsl_sensor_adc[j][k + 1]) k++;
    r0 = dsl_sensor_adc[j][k];
    r1 = dsl_sensor_adc[j][k + 1];
    c0 = dsl_sensor_counts[j][k];
    c1 = dsl_sensor_counts[j][k + 1];
    num = (reading - r0) * (c1 - c0);
    den = r1 - r0;
    /* round half away from zero, as the Python side's rint does for these magnitudes */
    return c0 + (num >= 0 ? (num + den / 2) / den : -((-num + den / 2) / den));
}
#endif

#endif
