/*
 * dsl_stepper.h - step/dir pulses from a stream's counts: portable C99, integers only.
 *
 * Each sample period is split into DSL_SUBTICKS ticks of a timer interrupt. At tick 0 the new
 * sample's count differences are taken and the direction pins set (so every direction change
 * comes a whole tick before the next step: set-up time for any driver); ticks 1..DSL_SUBTICKS-1
 * carry the steps, spread evenly by a Bresenham accumulator per axis. An axis can take up to
 * DSL_SUBTICKS - 1 (<= 254) steps per sample; more is counted in `overruns` and played as fast as
 * the ticks allow over the next samples (never dropped: the position always converges to the counts).
 */
#ifndef DSL_STEPPER_H
#define DSL_STEPPER_H

#include <stdint.h>

#ifndef DSL_SUBTICKS
#define DSL_SUBTICKS 32 /* 32 kHz at 1 kHz samples: 31 steps per ms per axis at most */
#endif
#ifndef DSL_STEP_AXES
#define DSL_STEP_AXES 4
#endif

/* The tick interrupt works on 8-bit counters only (it runs tens of thousands of times a second
   on an 8-bit MCU); 32-bit positions are updated once per sample. */
typedef struct {
    int32_t pos[DSL_STEP_AXES];   /* where the steps issued and scheduled take each axis, counts */
    uint8_t todo[DSL_STEP_AXES];  /* steps of this sample still to issue */
    uint8_t acc[DSL_STEP_AXES];   /* Bresenham accumulators */
    uint8_t n[DSL_STEP_AXES];     /* steps this sample */
    uint8_t dir_mask;             /* bit a set: axis a moves towards higher counts */
    uint8_t tick;                 /* 0: next is a sample start; 1..DSL_SUBTICKS-1: step slots */
    uint32_t overruns;            /* samples whose steps did not fit in one period */
} dsl_stepper;

static void dsl_stepper_init(dsl_stepper *s, const int32_t *start, uint8_t axes)
{
    uint8_t a;
    for (a = 0; a < DSL_STEP_AXES; a++) {
        s->pos[a] = a < axes ? start[a] : 0;
        s->todo[a] = s->acc[a] = s->n[a] = 0;
    }
    s->dir_mask = 0;
    s->tick = 0;
    s->overruns = 0;
}

/* A sample start: take its counts; returns the direction mask to put on the pins. Steps that do
   not fit in this period (an overrun) stay in the difference and are issued in the next ones. */
static uint8_t dsl_stepper_sample(dsl_stepper *s, const int32_t *counts, uint8_t axes)
{
    uint8_t a, over = 0;
    for (a = 0; a < axes; a++) {
        int32_t d = counts[a] - s->pos[a];
        uint32_t m = (uint32_t)(d < 0 ? -d : d);
        if (d > 0) s->dir_mask |= (uint8_t)(1u << a);
        else if (d < 0) s->dir_mask &= (uint8_t)~(1u << a);
        if (m > DSL_SUBTICKS - 1) {
            m = DSL_SUBTICKS - 1;
            over = 1;
        }
        s->pos[a] += d < 0 ? -(int32_t)m : (int32_t)m;
        s->n[a] = s->todo[a] = (uint8_t)m;
        s->acc[a] = 0;
    }
    s->overruns += over;
    s->tick = 1;
    return s->dir_mask;
}

/* A step slot (ticks 1..DSL_SUBTICKS-1): the axes to step now (bit mask); the caller pulses them.
   Each axis's n steps fall evenly over the DSL_SUBTICKS - 1 slots. */
static uint8_t dsl_stepper_tick(dsl_stepper *s, uint8_t axes)
{
    uint8_t a, mask = 0, left = (uint8_t)(DSL_SUBTICKS - s->tick); /* slots from this one on */
    for (a = 0; a < axes; a++) {
        uint8_t t = s->todo[a];
        if (!t) continue;
        s->acc[a] = (uint8_t)(s->acc[a] + s->n[a]);
        if (s->acc[a] >= DSL_SUBTICKS - 1 || t >= left) {
            if (s->acc[a] >= DSL_SUBTICKS - 1) s->acc[a] = (uint8_t)(s->acc[a] - (DSL_SUBTICKS - 1));
            s->todo[a] = (uint8_t)(t - 1);
            mask |= (uint8_t)(1u << a);
        }
    }
    s->tick++;
    return mask;
}

#endif
