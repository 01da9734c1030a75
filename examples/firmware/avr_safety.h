/*
 * avr_safety.h - what every AVR player does around the motion: the hardware watchdog and the
 * error line. Include after avr_serial.h and dsl_player.h.
 *
 * The watchdog (avr/wdt.h) resets the board when the main loop stops coming round for
 * SAFETY_WDT (500 ms; the longest pass is a few ms): a reset puts every pin back to an input, so
 * the RAMPS heater MOSFETs (pulled down) switch off and no step pulse follows. The player then
 * starts again, sees the watchdog's reset flag and reports it as its verdict instead of waiting
 * for a stream: the host's sender ends with that line.
 */
#ifndef AVR_SAFETY_H
#define AVR_SAFETY_H

#include <avr/io.h>
#include <avr/pgmspace.h>
#include <avr/wdt.h>
#include <stdint.h>

#define SAFETY_WDT WDTO_500MS

static uint8_t safety_reset_cause __attribute__((section(".noinit")));

/* Runs before main's set-up: after a watchdog reset the watchdog stays on at its shortest period
   (16 ms), which would reset the board again during its start. */
void safety_early(void) __attribute__((naked, used, section(".init3")));
void safety_early(void)
{
    safety_reset_cause = MCUSR;
    MCUSR = 0;
    wdt_disable();
}

static void safety_start(void) { wdt_enable(SAFETY_WDT); }

static uint8_t safety_watchdog_reset(void) { return (safety_reset_cause & _BV(WDRF)) != 0; }

/* The player's own error in full ("block N at byte offset M: <cause>"): its cause stays in flash,
   so no RAM holds the text and nothing is cut. */
static void serial_player_error(const dsl_player *p)
{
    if (p->error_in_header) {
        serial_puts_P(PSTR("header: "));
    } else {
        serial_puts_P(PSTR("block "));
        serial_putu(p->rx_blocks);
        serial_puts_P(PSTR(" at byte offset "));
        serial_putu(p->record_offset);
        serial_puts_P(PSTR(": "));
    }
    serial_puts_P(p->error_what);
}

/* A temperature in tenths of a degree C as "-12.3". */
__attribute__((unused)) static void serial_put_x10(int16_t t)
{
    if (t < 0) {
        serial_put('-');
        t = (int16_t)-t;
    }
    serial_putu((uint32_t)t / 10);
    serial_put('.');
    serial_put((uint8_t)('0' + t % 10));
}

#endif
