/*
 * dsl_thermistor.h - the RAMPS thermistors: 100k NTC, beta 3950, 4.7k pull-up to 5 V, read by a
 * 10-bit ADC referenced to AVCC. One table for the Mega player (which switches its heaters from
 * it) and the simulator harness (whose thermal model turns a temperature into the reading the
 * player would get). Portable C99; the table lives in flash on AVR.
 */
#ifndef DSL_THERMISTOR_H
#define DSL_THERMISTOR_H

#include <stdint.h>

#ifdef __AVR__
#include <avr/pgmspace.h>
#define DSL_NTC_READ(p) pgm_read_word(p)
#else
#ifndef PROGMEM
#define PROGMEM
#endif
#define DSL_NTC_READ(p) (*(p))
#endif

/* The reading at 0, 10, ... 300 C; it falls as the temperature rises. */
static const uint16_t dsl_ntc_adc[31] PROGMEM = {
    1009, 1000, 986, 966, 940, 905, 860, 807, 747, 680, 611, 542, 475, 412, 355, 305, 261, 223, 191, 163,
    140, 120, 104, 90, 78, 68, 60, 52, 46, 41, 36};

#if defined(__GNUC__)
#define DSL_NTC_MAYBE_UNUSED __attribute__((unused))
#else
#define DSL_NTC_MAYBE_UNUSED
#endif

/* The ADC reading at a temperature in tenths of a degree C (linear between the table's points). */
DSL_NTC_MAYBE_UNUSED static uint16_t dsl_ntc_adc_for_celsius_x10(int32_t t10)
{
    uint8_t k;
    int32_t lo, hi;
    if (t10 <= 0) return 1023;
    k = (uint8_t)(t10 / 100);
    if (k >= 30) return DSL_NTC_READ(&dsl_ntc_adc[30]);
    lo = DSL_NTC_READ(&dsl_ntc_adc[k]);
    hi = DSL_NTC_READ(&dsl_ntc_adc[k + 1]);
    return (uint16_t)(lo + (hi - lo) * (t10 - 100 * (int32_t)k) / 100);
}

/* The temperature (tenths of a degree C) a reading stands for: the table read the other way,
   0 C at and beyond its cold end, 300 C beyond its hot end. For the heater checks (ten times a
   second), never in the sample replay. */
DSL_NTC_MAYBE_UNUSED static int16_t dsl_ntc_celsius_x10_for_adc(uint16_t a)
{
    uint8_t k;
    uint16_t lo = DSL_NTC_READ(&dsl_ntc_adc[0]), hi;
    if (a >= lo) return 0;
    for (k = 1; k < 31; k++, lo = hi) {
        hi = DSL_NTC_READ(&dsl_ntc_adc[k]);
        if (a >= hi) return (int16_t)(100 * (k - 1) + (int32_t)100 * (lo - a) / (lo - hi));
    }
    return 3000;
}

#endif
