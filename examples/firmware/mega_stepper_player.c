/*
 * mega_stepper_player.c - step/dir steppers on an Arduino Mega 2560 + RAMPS 1.4 (the Atlas
 * five-bar; the Kossel with CONFIG=config/linear_kossel.h), played from a deltaslice stream
 * received over serial (avr_serial.h's credit flow control).
 *
 *   joint 1  X: step D54 (PF0), dir D55 (PF1), enable D38 (PD7)
 *   joint 2  Y: step D60 (PF6), dir D61 (PF7), enable D56 (PF2)
 *   joint 3  Z: step D46 (PL3), dir D48 (PL1), enable D62 (PK0)
 *   tool     E0: step D26 (PA4), dir D28 (PA6), enable D24 (PA2)
 *   heaters  hot end D10 (PB4) with the thermistor on A13, bed D8 (PH5) with A14
 *            (DSL_THERM_HOTEND, DSL_THERM_BED: the simulated build uses A5 and A6)
 *   strobe   D13 (PB7, the LED) toggles at every sample (a scope or the simulator counts them)
 *   E-stop   D41 (PG0, Marlin's KILL_PIN on the RAMPS), a normally closed switch to GND: the pin
 *            reading high (the switch pressed, or its wire broken) stops everything
 *   end stops X min D3 (PE5) / max D2 (PE4), Y min D14 (PJ1) / max D15 (PJ0), Z min D18 (PD3) /
 *            max D19 (PD2), normally closed to GND: high is tripped (or a broken wire); the
 *            printer file's [homing] says which of them a joint has (dsl_config.h)
 *
 * Timer1 interrupts DSL_SUBTICKS times per sample period; dsl_stepper.h spreads each sample's
 * count differences evenly over the period. At the first sample the joints with end stops are
 * homed and taken to it (the rest pose); a joint without one must be put there by hand.
 * Heater events switch the heaters bang-bang (2 C hysteresis) from the thermistors (100k NTC,
 * beta 3950, 4.7k pull-up: dsl_thermistor.h), read every 100 ms; a wait event holds the sample
 * clock until the heater is within 2 C, and the board sends "# heating" once a second meanwhile
 * (a keep-alive outside the serial protocol: the host ignores it but hears the board is alive).
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/pgmspace.h>
#include <stdint.h>

#define USART_RX_vect_NAME USART0_RX_vect
#include "avr_serial.h"

#define DSL_BUFFERS 2
#define DSL_ERROR_LEN 1 /* the message is printed whole from flash (avr_safety.h), not kept */
#include "dsl_player.h"
#include "avr_safety.h"
#include "dsl_stepper.h"
#include "dsl_thermistor.h"
#include DSL_CONFIG

#define AXES 4
#ifndef RING
/* decoded samples waiting for the step interrupt (16 bytes each): 32 ms of playback at 1 kHz, so
   a block's decode, the serial bursts and the heater reads never starve the step clock (with 4 the
   simulated Mega ended the Kossel test stream 394 ms late, with 16 110 ms, with 32 1 ms) */
#define RING 32
#endif

static dsl_player player;
static dsl_stepper stepper;
static int32_t ring[RING][AXES];
static volatile uint8_t ring_head, ring_count; /* the step interrupt takes from ring_head */
static uint8_t ring_tail; /* the next free slot: only the main loop reads or writes it */
static volatile uint8_t playing, held; /* held: a wait event stops the clock */
static volatile uint8_t idle;            /* the last sample's steps are all issued and none waits */
static volatile uint32_t samples_played;

/* The thermistors' ADC channels: A13 and A14 on the RAMPS. simavr 1.6 keeps analog inputs for
   ADC0..7 only, so the simulated build (make sim) moves them to A5 and A6. */
#ifndef DSL_THERM_HOTEND
#define DSL_THERM_HOTEND 13
#endif
#ifndef DSL_THERM_BED
#define DSL_THERM_BED 14
#endif

static uint16_t adc_read(uint8_t channel)
{
    ADMUX = _BV(REFS0) | (channel & 7);
    ADCSRB = channel & 8 ? _BV(MUX5) : 0;
    ADCSRA = _BV(ADEN) | _BV(ADSC) | _BV(ADPS2) | _BV(ADPS1) | _BV(ADPS0);
    while (ADCSRA & _BV(ADSC)) {
    }
    return ADC;
}

/* Heaters: [0] hot end, [1] bed, bang-bang with 2 C hysteresis around the set point, guarded as
   Marlin guards its heaters (the printer file's [safety], in dsl_config.h, tenths of a degree C and
   of a second): a reading outside min..max or a sensor open or shorted, a heater that rises too
   little while it heats, or stays too far below its set point once there. Any fault stops the
   machine (halt_fault). */
#define HEATER_POLL_TICKS 6250u /* 100 ms of Timer3 (/256): the thermistors are read 10 times a second */
#define ADC_OPEN 1016  /* below -5 C: no thermistor in a room, a broken wire or connector */
#define ADC_SHORT 16   /* over 350 C: a short, not a temperature */
static const int16_t heater_min[2] = DSL_CFG_HEATER_MIN_X10, heater_max[2] = DSL_CFG_HEATER_MAX_X10;
static const uint16_t heating_period[2] = DSL_CFG_HEATING_PERIOD_DS, hold_period[2] = DSL_CFG_HOLD_PERIOD_DS;
static const int16_t heating_gain[2] = DSL_CFG_HEATING_GAIN_X10, hold_drop[2] = DSL_CFG_HOLD_DROP_X10;
static int16_t heater_target[2];    /* 0: off */
static int16_t heater_temp[2];
static uint8_t heater_holding[2];   /* reached its set point since it was set */
static int16_t watch_base[2];       /* heating: the temperature at the start of this watch period */
static uint16_t watch_polls[2], drop_polls[2];
static uint8_t waiting_for = 0xFF;
static const char heater_name0[] PROGMEM = "hot end", heater_name1[] PROGMEM = "bed";

static void heaters_off(void)
{
    PORTB &= (uint8_t)~_BV(PB4);
    PORTH &= (uint8_t)~_BV(PH5);
}

/* Steppers disabled (enable pins high), as Marlin's kill() leaves them: no step can follow and
   the drivers stop powering the coils. */
static void motors_off(void)
{
    TIMSK1 = 0;
    PORTD |= _BV(PD7);
    PORTF |= _BV(PF2);
    PORTK |= _BV(PK0);
    PORTA |= _BV(PA2);
}

/* The safe state for good: heaters off, motion stopped, the line ended, the watchdog fed by a
   loop that does nothing else (and keeps the outputs off). */
static void halt(void)
{
    serial_put('\n');
    for (;;) {
        heaters_off();
        motors_off();
        wdt_reset();
    }
}

/* Heaters off and motors off at once, then "ERR <heater>: " for the caller to finish. */
static void fault(uint8_t h)
{
    heaters_off();
    motors_off();
    serial_puts_P(PSTR("ERR "));
    serial_puts_P(h ? heater_name1 : heater_name0);
    serial_puts_P(PSTR(": "));
}

static void heater_set(uint8_t h, int32_t t10)
{
    heater_target[h] = (int16_t)(t10 > 0 ? t10 : 0);
    heater_holding[h] = heater_target[h] && heater_temp[h] >= heater_target[h] - hold_drop[h];
    watch_base[h] = heater_temp[h];
    watch_polls[h] = drop_polls[h] = 0;
    if (t10 >= heater_max[h]) {
        fault(h);
        serial_puts_P(PSTR("set point "));
        serial_put_x10(heater_target[h]);
        serial_puts_P(PSTR(" C at or over the maximum "));
        serial_put_x10(heater_max[h]);
        serial_puts_P(PSTR(" C"));
        halt();
    }
}

/* Switch a heater's pin. Through a pointer the port is read, changed and written back, not set
   by one sbi/cbi: the step interrupt toggling the strobe on the same port in between would be
   undone (a sample strobed twice), so the interrupts wait. */
static void heater_pin(volatile uint8_t *port, uint8_t bit, uint8_t on)
{
    uint8_t sreg = SREG;
    cli();
    if (on) *port |= bit;
    else *port &= (uint8_t)~bit;
    SREG = sreg;
}

/* Read, check and switch one heater; 1 when it is within 2 C below its set point or hotter. */
static uint8_t heater_update(uint8_t h)
{
    uint16_t a = adc_read(h ? DSL_THERM_BED : DSL_THERM_HOTEND);
    volatile uint8_t *port = h ? &PORTH : &PORTB;
    uint8_t bit = h ? _BV(PH5) : _BV(PB4);
    int16_t t = dsl_ntc_celsius_x10_for_adc(a), target = heater_target[h];
    heater_temp[h] = t;
    /* an unset heater's sensor may be absent (a cold bed reads open), but never hot */
    if (a <= ADC_SHORT || (target && a >= ADC_OPEN)) {
        fault(h);
        serial_puts_P(a <= ADC_SHORT ? PSTR("thermistor shorted (ADC ") : PSTR("thermistor open (ADC "));
        serial_putu(a);
        serial_put(')');
        halt();
    }
    if (t > heater_max[h] || (target && t < heater_min[h])) {
        fault(h);
        serial_put_x10(t);
        serial_puts_P(t > heater_max[h] ? PSTR(" C, over the maximum ") : PSTR(" C, under the minimum "));
        serial_put_x10(t > heater_max[h] ? heater_max[h] : heater_min[h]);
        serial_puts_P(PSTR(" C"));
        halt();
    }
    if (!target) {
        heater_pin(port, bit, 0);
        return 0;
    }
    if (!heater_holding[h]) {
        if (t >= target - hold_drop[h]) {
            heater_holding[h] = 1;
        } else if (++watch_polls[h] >= heating_period[h]) {
            if (t < watch_base[h] + heating_gain[h]) {
                fault(h);
                serial_puts_P(PSTR("heating failed (thermal runaway): rose "));
                serial_put_x10((int16_t)(t - watch_base[h]));
                serial_puts_P(PSTR(" C in "));
                serial_putu(heating_period[h] / 10);
                serial_puts_P(PSTR(" s, under "));
                serial_put_x10(heating_gain[h]);
                serial_puts_P(PSTR(" C"));
                halt();
            }
            watch_base[h] = t;
            watch_polls[h] = 0;
        }
    } else if (t < target - hold_drop[h]) {
        if (++drop_polls[h] >= hold_period[h]) {
            fault(h);
            serial_puts_P(PSTR("thermal runaway: "));
            serial_put_x10(t);
            serial_puts_P(PSTR(" C, more than "));
            serial_put_x10(hold_drop[h]);
            serial_puts_P(PSTR(" C under its set point "));
            serial_put_x10(target);
            serial_puts_P(PSTR(" C for "));
            serial_putu(hold_period[h] / 10);
            serial_puts_P(PSTR(" s"));
            halt();
        }
    } else {
        drop_polls[h] = 0;
    }
    if (t > target + 20) heater_pin(port, bit, 0);
    else if (t < target - 20) heater_pin(port, bit, 1);
    return t >= target - 20;
}

#define ESTOP_OPEN() (PING & _BV(PG0))

static void pins_init(void)
{
    DDRG &= (uint8_t)~_BV(PG0); /* the E-stop, pulled up: open reads high */
    PORTG |= _BV(PG0);
    PORTE |= _BV(PE4) | _BV(PE5); /* the end stops (inputs), pulled up: tripped reads high */
    PORTJ |= _BV(PJ0) | _BV(PJ1);
    PORTD |= _BV(PD2) | _BV(PD3);
    DDRF |= _BV(PF0) | _BV(PF1) | _BV(PF6) | _BV(PF7) | _BV(PF2);
    DDRD |= _BV(PD7);
    DDRL |= _BV(PL3) | _BV(PL1);
    DDRK |= _BV(PK0);
    DDRA |= _BV(PA4) | _BV(PA6) | _BV(PA2);
    DDRB |= _BV(PB4) | _BV(PB7);
    DDRH |= _BV(PH5);
    PORTD &= (uint8_t)~_BV(PD7); /* drivers enabled (active low) */
    PORTF &= (uint8_t)~_BV(PF2);
    PORTK &= (uint8_t)~_BV(PK0);
    PORTA &= (uint8_t)~_BV(PA2);
}

static void set_dirs(uint8_t m)
{
    if (m & 1) PORTF |= _BV(PF1); else PORTF &= (uint8_t)~_BV(PF1);
    if (m & 2) PORTF |= _BV(PF7); else PORTF &= (uint8_t)~_BV(PF7);
    if (m & 4) PORTL |= _BV(PL1); else PORTL &= (uint8_t)~_BV(PL1);
    if (m & 8) PORTA |= _BV(PA6); else PORTA &= (uint8_t)~_BV(PA6);
}

static void pulse(uint8_t m)
{
    uint8_t f = (uint8_t)((m & 1 ? _BV(PF0) : 0) | (m & 2 ? _BV(PF6) : 0));
    PORTF |= f;
    if (m & 4) PORTL |= _BV(PL3);
    if (m & 8) PORTA |= _BV(PA4);
    __builtin_avr_delay_cycles(16); /* 1 us: A4988, DRV8825 and TMC drivers all take it */
    PORTF &= (uint8_t)~f;
    PORTL &= (uint8_t)~_BV(PL3);
    PORTA &= (uint8_t)~_BV(PA4);
}

/* The playback clock's rate, RATE_ONE = the stream's own: a feed hold (an underrun coming, a pause)
   ramps it to 0 and back, by rate_step per tick, so the samples are played exactly, only slower:
   every joint's velocity scales with the rate and its acceleration with the rate squared plus its
   velocity times the rate's change (DSL_CFG_RAMP_MS keeps that term within half its limit). A
   step tick comes when the phase accumulator passes RATE_ONE: never more often than at full rate. */
#define RATE_ONE 32768u
static volatile uint16_t rate, rate_target;
static uint16_t phase, rate_step = 1;
static volatile uint8_t warping; /* rate or its target below RATE_ONE: the tick's only extra test at full rate */

ISR(TIMER1_COMPA_vect)
{
    if (ESTOP_OPEN()) { /* at once, whatever the main loop is doing; it reports it */
        heaters_off();
        motors_off();
        return;
    }
    if (!playing || held) return;
    if (warping) {
        uint16_t r = rate, target = rate_target;
        if (r < target) r = target - r > rate_step ? r + rate_step : target;
        else if (r > target) r = r - target > rate_step ? r - rate_step : target;
        rate = r;
        if (r == RATE_ONE) warping = 0;
        phase += r;
        if (phase < RATE_ONE) return;
        phase -= RATE_ONE;
    }
    if (stepper.tick == 0 || stepper.tick >= DSL_SUBTICKS) {
        if (!ring_count) { /* an underrun the ramp did not foresee, or the end: the motors at rest */
            idle = 1;
            return;
        }
        idle = 0;
        set_dirs(dsl_stepper_sample(&stepper, ring[ring_head], AXES));
        ring_head = (uint8_t)((ring_head + 1) % RING);
        ring_count--;
        samples_played++;
        PINB = _BV(PB7); /* toggle the strobe */
        return;
    }
    pulse(dsl_stepper_tick(&stepper, AXES));
}

/* The rate the clock heads for: 0 during the host's feed hold, and while fewer samples are
   buffered than a ramp from full rate to a stop plays (ramp_samples: half the ramp's periods) and
   more are still to come (or an error ended the stream); full again once twice that many are in,
   or the receive side can take no more, or the stream is whole. */
static uint16_t ramp_samples = 1;

static void feed_hold_update(void)
{
    uint16_t avail, target = rate_target;
    uint8_t coming = player.rx_state != DSL_S_END && player.rx_state != DSL_S_ERROR;
    uint8_t full = player.q_count == DSL_BUFFERS || player.ev_count == DSL_MAX_EVENTS;
    uint32_t n = player.rx_samples - player.sample_index + ring_count;
    avail = n > 0xFFFF ? 0xFFFF : (uint16_t)n;
    if (serial_paused) target = 0;
    else if (avail < ramp_samples && (player.rx_state == DSL_S_ERROR || (coming && !full))) target = 0;
    else if (avail >= 2 * ramp_samples || full || !coming) target = RATE_ONE;
    if (target != rate_target) {
        cli();
        rate_target = target;
        warping = 1;
        sei();
    }
}

/* Every pass of every loop: the watchdog fed, the E-stop and the host's abort obeyed, a byte out of
   the protocol refused; each of these stops everything at once. */
static void safety_checks(void)
{
    wdt_reset();
    if (!ESTOP_OPEN() && !serial_abort && !serial_bad) return;
    heaters_off();
    motors_off();
    if (ESTOP_OPEN()) {
        serial_puts_P(PSTR("ERR emergency stop (D41 open): heaters off, motors off"));
    } else if (serial_abort) {
        serial_puts_P(PSTR("ERR aborted by the host: heaters off, motors off"));
    } else {
        serial_puts_P(PSTR("ERR serial: byte "));
        serial_putu(serial_bad);
        serial_puts_P(PSTR(" between chunks is no chunk length nor control (a sender of the unframed protocol?)"));
    }
    halt();
}

/* The stream's verdict. "OK": every sample played, heaters off, the motors holding the rest pose.
   An error of the stream (or made for another printer): the intact samples before it played, then
   heaters and motors off. */
/* poll() every 100 ms, from every loop that runs for long */
static uint16_t poll_last;
static void poll(void);

static void poll_due(void)
{
    if ((uint16_t)(TCNT3 - poll_last) < HEATER_POLL_TICKS) return;
    poll_last = (uint16_t)(poll_last + HEATER_POLL_TICKS);
    poll();
}

/* Homing, at the first sample (after the heating waits before it, as a print's start G-code heats
   then homes): every joint with an end stop steps towards it at its homing speed until the switch
   trips (there its count is DSL_CFG_HOME_COUNTS), then all step to the first sample (the rest
   pose), where the stream starts. The heaters go on being regulated meanwhile. One approach, no
   second slower bump: the switch's repeatability is the rest pose's. A switch not found within
   the joint's range is a fault. */
static const int8_t home_dir[3] = DSL_CFG_HOME_DIR;

static uint8_t endstop_tripped(uint8_t a)
{
    uint8_t high = home_dir[a] > 0;
    if (a == 0) return high ? (PINE & _BV(PE4)) != 0 : (PINE & _BV(PE5)) != 0;
    if (a == 1) return high ? (PINJ & _BV(PJ0)) != 0 : (PINJ & _BV(PJ1)) != 0;
    return high ? (PIND & _BV(PD2)) != 0 : (PIND & _BV(PD3)) != 0;
}

static void home_fault(uint8_t a, const char *what_P)
{
    heaters_off();
    motors_off();
    serial_puts_P(PSTR("ERR joint "));
    serial_putu(a + 1u);
    serial_puts_P(what_P);
    halt();
}

/* Step the axes of `todo` (steps per axis, directions set) each at its own period, in Timer3 ticks
   (16 us). seek 1: an axis stops when its switch trips, running out of steps is a fault; seek 2
   (backing off a switch tripped at the start): an axis stops once its switch is released, and
   running out of steps is a fault (a broken wire reads tripped: open). */
static void home_steps(uint32_t *todo, uint8_t seek)
{
    static const uint16_t step_us[3] = DSL_CFG_HOME_STEP_US;
    uint16_t next[3], now = TCNT3;
    uint8_t a, active = 0;
    for (a = 0; a < 3; a++) {
        next[a] = now;
        if (todo[a] && !(seek && endstop_tripped(a) == (seek == 1))) active |= (uint8_t)(1u << a);
    }
    while (active) {
        uint8_t m = 0;
        safety_checks();
        poll_due();
        now = TCNT3;
        for (a = 0; a < 3; a++) {
            if (!(active & (1u << a)) || (int16_t)(now - next[a]) < 0) continue;
            next[a] = (uint16_t)(next[a] + step_us[a] / 16u);
            m |= (uint8_t)(1u << a);
            if (--todo[a] == 0) active &= (uint8_t)~(1u << a);
        }
        if (!m) continue;
        pulse(m);
        for (a = 0; a < 3 && seek; a++) {
            if (!(m & (1u << a))) continue;
            if (endstop_tripped(a) == (seek == 1)) {
                active &= (uint8_t)~(1u << a);
                todo[a] = 1; /* found (or released) */
            } else if (!(active & (1u << a))) {
                home_fault(a, seek == 1 ? PSTR(": end stop not found within the joint's range")
                                        : PSTR(": end stop tripped and not released by backing off (a broken wire?)"));
            }
        }
    }
}

/* Home the joints with end stops and take them to `first`; a joint without one is where the
   stream's first sample is (put there by hand). */
static void home(const int32_t *first)
{
    static const uint32_t max_steps[3] = DSL_CFG_HOME_MAX_STEPS;
    static const int32_t home_counts[3] = DSL_CFG_HOME_COUNTS;
    uint32_t todo[3];
    uint8_t a, dirs = 0, any = 0;
    for (a = 0; a < 3; a++) {
        todo[a] = home_dir[a] ? max_steps[a] : 0;
        if (home_dir[a] > 0) dirs |= (uint8_t)(1u << a);
        any |= home_dir[a] != 0;
    }
    if (!any) return;
    /* a switch tripped already: back off it first (a sixteenth of the range at most), as Marlin
       bumps, so a broken wire is not taken for the switch */
    {
        uint32_t off[3];
        for (a = 0; a < 3; a++) off[a] = home_dir[a] && endstop_tripped(a) ? max_steps[a] / 16 : 0;
        set_dirs((uint8_t)~dirs);
        __builtin_avr_delay_cycles(32);
        home_steps(off, 2);
    }
    set_dirs(dirs);
    __builtin_avr_delay_cycles(32); /* direction set-up before the first step */
    home_steps(todo, 1);
    dirs = 0;
    for (a = 0; a < 3; a++) {
        int32_t d = home_dir[a] ? first[a] - home_counts[a] : 0;
        if (d > 0) dirs |= (uint8_t)(1u << a);
        todo[a] = (uint32_t)(d < 0 ? -d : d);
    }
    set_dirs(dirs);
    __builtin_avr_delay_cycles(32);
    home_steps(todo, 0);
}

static void stop(const char *message_P)
{
    while (playing && !idle && (rate || rate_target)) { /* (a clock ramped to a stop plays no more) */
        safety_checks();
    }
    TIMSK1 = 0;
    heaters_off();
    if (message_P) {
        serial_puts_P(PSTR("ERR "));
        serial_puts_P(message_P);
    } else if (player.rx_state == DSL_S_ERROR) {
        serial_puts_P(PSTR("ERR "));
        serial_player_error(&player);
    } else {
        serial_puts_P(PSTR("OK "));
        serial_putu(player.sample_index);
        serial_put('\n');
        for (;;) {
            heaters_off();
            wdt_reset();
        }
    }
    halt();
}

/* Every 100 ms: the heaters, the heating wait and the host. */
static void poll(void)
{
    static uint8_t keepalive, silent, last_heard, heard;
    static uint16_t wait_polls;
    uint8_t ready0 = heater_update(0), ready1 = heater_update(1), rx = serial_heard;
    if (waiting_for == 0xFF) {
        keepalive = 0;
        wait_polls = 0;
    } else if (waiting_for ? ready1 : ready0) {
        waiting_for = 0xFF; /* (a wait right after this one goes on counting) */
        held = 0;
    } else if (++wait_polls >= DSL_CFG_WAIT_TIMEOUT_DS) {
        fault(waiting_for);
        serial_puts_P(PSTR("not at its set point after the longest heating wait, "));
        serial_putu(DSL_CFG_WAIT_TIMEOUT_DS / 10);
        serial_puts_P(PSTR(" s"));
        halt();
    } else if (++keepalive >= 10) {
        /* a wait lasts tens of seconds: say so once a second, so the host (deltaslice send,
           which ignores lines outside the protocol) does not take the silence for a dead board */
        keepalive = 0;
        serial_puts_P(PSTR("# heating\n"));
    }
    /* No host, no heat: bytes asked for (a credit outstanding) and none arriving, or a feed hold
       whose host stopped repeating it, means the host is gone. A board that asks for nothing
       (buffers full, a heating wait) waits without limit, and after the end record nothing more
       is due. */
    if (rx != last_heard) {
        last_heard = rx;
        heard = 1;
        silent = 0;
    } else if (heard && (serial_paused || (serial_granted != serial_received && player.rx_state != DSL_S_END &&
                                          player.rx_state != DSL_S_ERROR))) {
        if (++silent >= DSL_CFG_HOST_TIMEOUT_DS) {
            heaters_off();
            motors_off();
            serial_puts_P(PSTR("ERR host silent for "));
            serial_putu(DSL_CFG_HOST_TIMEOUT_DS / 10);
            serial_puts_P(PSTR(" s: heaters off, motors off"));
            halt();
        }
    } else {
        silent = 0;
    }
}

int main(void)
{
    int32_t counts[DSL_MAX_CHANNELS];
    uint8_t started = 0, hb = 0, have = 0, k;

    pins_init();
    TCCR3A = 0;
    TCCR3B = _BV(CS32); /* Timer3 free running at 62.5 kHz: the heaters' clock */
    serial_init();
    dsl_init(&player);
    if (safety_watchdog_reset()) {
        motors_off();
        serial_puts_P(PSTR("ERR watchdog reset: the player hung; heaters off, motors off"));
        halt();
    }
    safety_start();
    heater_update(0); /* the readings before any set point (and a shorted sensor at power-up) */
    heater_update(1);
    poll_last = TCNT3;
    sei();
    for (;;) {
        int r;
        safety_checks();
        serial_grant();
        if (!have) have = serial_take(&hb);
        while (have && dsl_feed(&player, &hb, 1) == 1) have = serial_take(&hb);
        poll_due();
        if (!started) {
            if (player.rx_state == DSL_S_ERROR) stop(0);
            if (!player.header_ok) continue;
            if (player.fingerprint != DSL_CFG_FINGERPRINT) stop(PSTR("stream made for another printer (fingerprint)"));
            if (player.q_count < DSL_BUFFERS && player.rx_state != DSL_S_END) continue;
            OCR1A = (uint16_t)(1000000000UL / player.rate_mhz * 16 / DSL_SUBTICKS - 1); /* /1: 62.5 ns ticks */
            {   /* the ramp in ticks of the step clock, and the samples it plays from full rate */
                uint32_t ticks = (uint32_t)DSL_CFG_RAMP_MS * DSL_SUBTICKS * (player.rate_mhz / 1000u) / 1000u;
                rate_step = ticks >= RATE_ONE ? 1 : (uint16_t)(RATE_ONE / (ticks ? ticks : 1));
                ramp_samples = (uint16_t)((uint32_t)RATE_ONE / rate_step / DSL_SUBTICKS / 2 + 8);
            }
            rate = rate_target = RATE_ONE;
            TCCR1A = 0;
            TCCR1B = _BV(WGM12) | _BV(CS10);
            started = 1;
        }
        if (started) feed_hold_update();
        if (ring_count >= RING || waiting_for != 0xFF) continue;
        r = dsl_next(&player, counts);
        if (r == DSL_EVENT) {
            uint8_t kind = player.event_kind;
            if (kind >= DSL_EV_HOTEND_SET && kind <= DSL_EV_BED_WAIT) {
                uint8_t h = kind >= DSL_EV_BED_SET;
                heater_set(h, player.event_value);
                if ((kind == DSL_EV_HOTEND_WAIT || kind == DSL_EV_BED_WAIT) && player.event_value > 0) {
                    /* hold the clock once the samples before the event are played */
                    while (playing && !idle) {
                        safety_checks();
                    }
                    held = 1;
                    waiting_for = h;
                }
            }
            continue;
        }
        if (r == DSL_SAMPLE) {
            if (!playing) { /* homed to the first sample, or put there by hand */
                home(counts);
                dsl_stepper_init(&stepper, counts, AXES);
            }
            /* the slot from the main loop's own index: ring_head + ring_count read here could mix
               the values before and after a step interrupt and overwrite a queued sample */
            for (k = 0; k < AXES; k++) ring[ring_tail][k] = counts[k];
            ring_tail = (uint8_t)((ring_tail + 1) % RING);
            cli();
            ring_count++;
            if (!playing) {
                playing = 1;
                TIMSK1 = _BV(OCIE1A);
            }
            sei();
        } else if (r == DSL_DONE || r == DSL_ERROR) {
            stop(0);
        }
    }
}
