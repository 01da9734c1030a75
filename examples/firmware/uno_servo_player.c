/*
 * uno_servo_player.c - the ETITC delta on an Arduino Uno (ATmega328P, 16 MHz): three hobby servos
 * and the extruder stepper, played from a deltaslice stream received over serial (avr_serial.h).
 *
 *   servos   D3, D5, D6: one pulse after the other every 20 ms, each edge at an exact tick of
 *            Timer2 (0.5 us), so the widths are exact to a fraction of a microsecond
 *   extruder D2 step, D4 dir (a StepStick); D8 enable (low = on)
 *   samples  Timer1 (CTC) ticks once per sample period (1 kHz: 2000 ticks of 0.5 us); D13 (PB5,
 *            the LED) toggles at every sample played (a scope or the simulator times them)
 *
 * Joint counts are the pulse widths in microseconds (the printer file's zero_count and
 * counts_per_unit); each 20 ms frame sends the widths of the sample being played at its start.
 * Before the stream starts the servos hold the rest pose of dsl_config.h, which is where every
 * deltaslice trajectory starts and parks, so attaching them does not make them jump.
 * Build: make -C examples/firmware uno (CONFIG_UNO=config/delta_etitc.h, the default).
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/pgmspace.h>
#include <stdint.h>

#define USART_RX_vect_NAME USART_RX_vect
#include "avr_serial.h"

#define DSL_BUFFERS 2
#define DSL_ERROR_LEN 1 /* the message is printed whole from flash (avr_safety.h), not kept */
#include "dsl_player.h"
#include "avr_safety.h"
#include DSL_CONFIG

#define SERVOS 3
#define FRAME_TICKS 40000u /* 20 ms at 0.5 us */

static dsl_player player;
static volatile uint16_t width_us[SERVOS]; /* the widths of the sample being played */
static volatile uint8_t sample_due;        /* a sample tick not yet played (0 or 1) */
static volatile uint8_t clock_on;          /* the sample ticks count once playback has started */
static uint16_t period_us = 1000;          /* the sample period (1 ms until the header says) */
static uint16_t frame_us;                  /* time since the last frame start */

/* The servo pulses, one after the other in each 20 ms frame, timed by Timer2 (0.5 us ticks, 8 bits).
   Its compare interrupt is re-armed in laps of at most 100 us until the next edge is near; the last
   one comes 20 us early and waits (interrupts are off in an interrupt) for the exact tick, so every edge comes the
   same few cycles after its tick and the widths are exact to a fraction of a microsecond, whatever
   the other interrupts (serial, sample clock) were doing. */
static const uint8_t servo_pin[SERVOS] = {_BV(PD3), _BV(PD5), _BV(PD6)}; /* D3, D5, D6 */
static uint8_t servo_k, servo_high;   /* the servo whose edge comes next; is it high now */
static uint16_t servo_left;           /* ticks from the last compare to that edge */

static uint16_t clamp_width(int32_t c)
{
    return (uint16_t)(c < 500 ? 500 : c > 2500 ? 2500 : c); /* a servo's safe pulse range */
}

static void servo_frame(void)
{
    servo_k = 0;
    servo_high = 0;
    OCR2A = (uint8_t)(TCNT2 + 16); /* a compare 8 us from now starts the chain */
    servo_left = 48;                /* the first rise 24 us after that */
    TIFR2 = _BV(OCF2A);
    TIMSK2 = _BV(OCIE2A);
}

ISR(TIMER2_COMPA_vect)
{
    uint8_t edge;
    /* every re-arming is at least 16 ticks ahead, so it is never behind the timer when this
       interrupt returns */
    if (servo_left > 240) { /* far: another lap */
        OCR2A = (uint8_t)(OCR2A + 200);
        servo_left = (uint16_t)(servo_left - 200);
        return;
    }
    if (servo_left > 56) { /* near: come back 20 us before the edge */
        OCR2A = (uint8_t)(OCR2A + servo_left - 40);
        servo_left = 40;
        return;
    }
    /* wait for the edge's tick with interrupts off (as they are in here: never re-enabled, so no
       other interrupt can delay the re-arming below past its compare) */
    edge = (uint8_t)(OCR2A + servo_left);
    while ((int8_t)(TCNT2 - edge) < 0) {
    }
    PIND = servo_pin[servo_k]; /* toggle: rise or fall */
    if (!servo_high) {
        servo_high = 1;
        servo_left = (uint16_t)(2 * width_us[servo_k]);
    } else {
        servo_high = 0;
        if (++servo_k == SERVOS) {
            TIMSK2 = 0;
            return;
        }
        servo_left = 60; /* the next servo rises 30 us later */
    }
    /* the next compare 8 us after this edge (the timer is at the edge now: a compare set there
       would come only after a whole lap) */
    OCR2A = (uint8_t)(edge + 16);
    servo_left = (uint16_t)(servo_left - 16);
}

/* The playback clock's rate (RATE_ONE: the stream's own), ramped by rate_step per period to 0 and
   back when the buffer runs low (as on the Mega: the samples played exactly, only slower, so the
   servos slow down and speed up rather than stop dead). A sample falls due when the phase passes
   RATE_ONE, one at a time: an underrun never leaves a backlog to play in a burst. */
#define RATE_ONE 32768u
static volatile uint16_t rate, rate_target;
static uint16_t phase, rate_step = 1, ramp_samples = 1;

/* Timer1 (CTC) ticks once per sample period: the sample clock and the 20 ms servo frames. */
ISR(TIMER1_COMPA_vect)
{
    if (clock_on) {
        if (rate < rate_target) rate = rate_target - rate > rate_step ? rate + rate_step : rate_target;
        else if (rate > rate_target) rate = rate - rate_target > rate_step ? rate - rate_step : rate_target;
        phase += rate;
        if (phase >= RATE_ONE) {
            phase -= RATE_ONE;
            sample_due = 1;
        }
    }
    frame_us = (uint16_t)(frame_us + period_us);
    if (frame_us >= 20000) {
        frame_us = (uint16_t)(frame_us - 20000);
        servo_frame();
    }
}

static void servos_init(void)
{
    static const int32_t rest[SERVOS] = DSL_CFG_REST_COUNTS;
    uint8_t k;
    for (k = 0; k < SERVOS; k++) width_us[k] = clamp_width(rest[k]);
    DDRB |= _BV(PB5);                       /* D13 the strobe */
    DDRD |= _BV(PD3) | _BV(PD5) | _BV(PD6); /* the servos */
    TCCR2A = 0;
    TCCR2B = _BV(CS21);                     /* Timer2 /8, normal mode */
    frame_us = 20000 - 500;      /* the first frame 0.5 ms after start */
    OCR1A = 2 * period_us - 1;
    TCCR1A = 0;
    TCCR1B = _BV(WGM12) | _BV(CS11); /* CTC, /8 */
    TIMSK1 = _BV(OCIE1A);
}

static int32_t e_pos;
static uint8_t e_started;

static void extruder_init(void)
{
    DDRD |= _BV(PD2) | _BV(PD4);
    DDRB |= _BV(PB0);
    PORTB &= (uint8_t)~_BV(PB0);
}

/* The extruder's count difference as step pulses (a few per sample at most). */
static void extruder_to(int32_t target)
{
    if (!e_started) {
        e_pos = target;
        e_started = 1;
        return;
    }
    if (target == e_pos) return;
    if (target > e_pos) PORTD |= _BV(PD4);
    else PORTD &= (uint8_t)~_BV(PD4);
    __builtin_avr_delay_cycles(16); /* direction set-up, 1 us */
    while (e_pos != target) {
        PORTD |= _BV(PD2);
        __builtin_avr_delay_cycles(32); /* 2 us step pulse */
        PORTD &= (uint8_t)~_BV(PD2);
        __builtin_avr_delay_cycles(32);
        e_pos += target > e_pos ? 1 : -1;
    }
}

/* The verdict, then nothing more is played. On an error the extruder's driver is disabled and the
   servos go on holding the last widths: a hobby servo without pulses goes limp (or holds, by
   model), and a limp rotary delta drops its platform onto the part; held, the arms stay put. */
static void stop(const char *message_P)
{
    clock_on = 0;
    if (message_P || player.rx_state == DSL_S_ERROR) {
        PORTB |= _BV(PB0);
        serial_puts_P(PSTR("ERR "));
        if (message_P) serial_puts_P(message_P);
        else serial_player_error(&player);
    } else {
        serial_puts_P(PSTR("OK "));
        serial_putu(player.sample_index);
    }
    serial_put('\n');
    for (;;) {
        wdt_reset();
    }
}

/* 0 during the host's feed hold, and while fewer samples are buffered than a ramp to a stop plays
   and more are coming; full again once twice that many are in, the buffers are full, or the
   stream is whole. */
static void feed_hold_update(void)
{
    uint16_t avail, target = rate_target;
    uint8_t coming = player.rx_state != DSL_S_END && player.rx_state != DSL_S_ERROR;
    uint8_t full = player.q_count == DSL_BUFFERS || player.ev_count == DSL_MAX_EVENTS;
    uint32_t n = player.rx_samples - player.sample_index;
    avail = n > 0xFFFF ? 0xFFFF : (uint16_t)n;
    if (serial_paused) target = 0;
    else if (avail < ramp_samples && (player.rx_state == DSL_S_ERROR || (coming && !full))) target = 0;
    else if (avail >= 2 * ramp_samples || full || !coming) target = RATE_ONE;
    if (target != rate_target) {
        cli();
        rate_target = target;
        sei();
    }
}

int main(void)
{
    int32_t counts[DSL_MAX_CHANNELS];
    uint8_t started = 0, held = 0, hb = 0, budget;

    servos_init();
    extruder_init();
    serial_init();
    dsl_init(&player);
    sei();
    if (safety_watchdog_reset()) stop(PSTR("watchdog reset: the player hung; the servos hold the rest pose"));
    safety_start();
    for (;;) {
        int r;
        wdt_reset();
        if (serial_abort) stop(PSTR("aborted by the host: the servos hold, the extruder is off"));
        if (serial_bad)
            stop(PSTR("serial: a byte between chunks is no chunk length nor control (a sender of the unframed protocol?)"));
        serial_grant();
        /* a few bytes per pass, so a burst of received bytes never delays a sample by more than
           a fraction of its period */
        for (budget = 16; budget; budget--) {
            if (!held) held = serial_take(&hb);
            if (!held || dsl_feed(&player, &hb, 1) != 1) break;
            held = 0;
        }
        if (!started) {
            if (player.rx_state == DSL_S_ERROR) stop(0);
            if (!player.header_ok) continue;
            if (player.fingerprint != DSL_CFG_FINGERPRINT) stop(PSTR("stream made for another printer (fingerprint)"));
            if (player.q_count < DSL_BUFFERS && player.rx_state != DSL_S_END) continue; /* fill both buffers first */
            cli();
            if (period_us != (uint16_t)(1000000000UL / player.rate_mhz)) { /* not 1 kHz: re-time the ticks */
                period_us = (uint16_t)(1000000000UL / player.rate_mhz);
                OCR1A = (uint16_t)(2 * period_us - 1); /* 0.5 us ticks: periods up to 32 ms */
                TCNT1 = 0;
            }
            {   /* the ramp in sample periods, and the samples it plays from full rate */
                uint32_t periods = (uint32_t)DSL_CFG_RAMP_MS * 1000u / period_us;
                rate_step = periods >= RATE_ONE ? 1 : (uint16_t)(RATE_ONE / (periods ? periods : 1));
                ramp_samples = (uint16_t)(RATE_ONE / rate_step / 2 + 8);
            }
            rate = rate_target = RATE_ONE;
            clock_on = 1;
            sei();
            started = 1;
        }
        feed_hold_update();
        if (player.rx_state == DSL_S_ERROR && !rate_target) { /* the clock ramps to a stop before the damage */
            uint16_t r;
            cli();
            r = rate;
            sei();
            if (!r) stop(0);
        }
        if (!sample_due) continue;
        r = dsl_next(&player, counts);
        if (r == DSL_SAMPLE) {
            uint8_t k;
            cli();
            sample_due--;
            for (k = 0; k < SERVOS; k++) width_us[k] = clamp_width(counts[k]);
            sei();
            PINB = _BV(PB5);
            extruder_to(counts[SERVOS]);
        } else if (r == DSL_DONE || r == DSL_ERROR) {
            stop(0);
        }
        /* DSL_EVENT: heater and fan events are not this board's (the ETITC hot end has its own
           controller). DSL_AGAIN: an underrun the ramp did not foresee; the servos hold the last
           widths and the sample due is played as soon as the bytes arrive. */
    }
}
