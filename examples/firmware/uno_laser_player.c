/*
 * uno_laser_player.c - the ESPE engraver's laser on an Arduino Uno (ATmega328P, 16 MHz): the PWM
 * duty of the laser driver's TTL input from the stream's power channel, as `deltaslice play
 * --laser PORT` sends it in real time beside the Dynamixel bus (the PC is the clock of both).
 *
 *   laser    D11 (OC2A): Timer2 fast PWM, 7.8 kHz, high for d of every 256 ticks (d = 0: the
 *            pin is disconnected from the timer and held low, so no glitch of one tick)
 *   link     USART0, 115200 baud, 3-byte frames KIND VALUE CHECK, CHECK = ~(KIND + VALUE):
 *                host -> board  'L' d   laser duty d (0..255), at every change and as a keep-alive
 *                               'E' 0   end: laser off; answers "OK <frames>"
 *                               'Q' 0   query: answers "LASER <timeout ms>"
 *                board -> host  "LASER 250\n" at power-up and to a query
 *                               "ERR <msg>\n" a bad frame, a UART error or a silent host
 *
 * The laser goes off on any error (a check byte that does not match, an unknown kind, a framing
 * or overrun error: a lost byte would shift every frame after it), on a host time-out (no frame
 * for LASER_TIMEOUT_MS while a job runs: the PC or its program died), at the end, and at reset
 * (the pin is an input until the player drives it low). After an error it stays off, and says
 * so to every frame, until the board is reset (opening its port does that). The time-out is
 * checked in the 1 ms timer interrupt, so a stuck main loop cannot hold the laser on, and the
 * watchdog resets a main loop stuck for 120 ms.
 * Build: make -C examples/firmware uno (build/uno_laser_player.hex).
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/pgmspace.h>
#include <avr/wdt.h>
#include <stdint.h>

#include "avr_uart.h"

#define LASER_TIMEOUT_MS 250
#define RING 32 /* a power of two */

static volatile uint8_t ring[RING], head, tail, uart_error;
static volatile uint16_t silent_ms; /* since the last good frame */
static volatile uint8_t armed;      /* a job runs: the time-out applies */
static volatile uint8_t failed;     /* the error latch: the laser stays off until reset */
static volatile uint8_t timed_out;  /* the timer interrupt saw the host go silent */
static uint32_t frames;

static void laser_off(void)
{
    TCCR2A = _BV(WGM21) | _BV(WGM20); /* OC2A disconnected: the pin is PORTB3, low */
    PORTB &= (uint8_t)~_BV(PB3);
}

static void laser_set(uint8_t duty)
{
    if (!duty || failed) {
        laser_off();
        return;
    }
    OCR2A = (uint8_t)(duty - 1); /* fast PWM: high for OCR2A + 1 ticks of 256 */
    TCCR2A = _BV(COM2A1) | _BV(WGM21) | _BV(WGM20);
}

ISR(USART_RX_vect)
{
    uint8_t status = UCSR0A, b = UDR0;
    if (status & (_BV(FE0) | _BV(DOR0))) uart_error = 1;
    if ((uint8_t)(head - tail) < RING) {
        ring[head & (RING - 1)] = b;
        head++;
    } else {
        uart_error = 1; /* the main loop fell behind: a byte is lost */
    }
}

/* 1 ms: the host time-out, acted on here so that nothing in the main loop can delay it */
ISR(TIMER1_COMPA_vect)
{
    if (!armed) return;
    if (++silent_ms >= LASER_TIMEOUT_MS) {
        laser_off();
        armed = 0;
        failed = 1;
        timed_out = 1;
    }
}

static const char *error_P; /* the first error, said again to every frame after it */

static void fail(const char *message_P)
{
    cli();
    failed = 1;
    armed = 0;
    laser_off();
    sei();
    if (!error_P) error_P = message_P;
    serial_puts_P(PSTR("ERR "));
    serial_puts_P(error_P);
    serial_put('\n');
}

static void ready(void)
{
    serial_puts_P(PSTR("LASER "));
    serial_putu(LASER_TIMEOUT_MS);
    serial_put('\n');
}

static void frame(uint8_t kind, uint8_t value, uint8_t check)
{
    if (check != (uint8_t) ~(uint8_t)(kind + value)) {
        fail(PSTR("bad frame (check byte): laser off until reset"));
        return;
    }
    if (failed) {
        fail(error_P ? error_P : PSTR("laser off until reset"));
        return;
    }
    frames++;
    if (kind == 'L') {
        cli();
        silent_ms = 0;
        armed = 1;
        laser_set(value);
        sei();
    } else if (kind == 'E') {
        cli();
        armed = 0;
        laser_off();
        sei();
        serial_puts_P(PSTR("OK "));
        serial_putu(frames);
        serial_put('\n');
        frames = 0;
    } else if (kind == 'Q') {
        ready();
    } else {
        fail(PSTR("unknown frame: laser off until reset"));
    }
}

int main(void)
{
    uint8_t got[3], n = 0;

    MCUSR = 0;
    wdt_enable(WDTO_120MS);
    DDRB |= _BV(PB3);
    laser_off();
    TCCR2B = _BV(CS21); /* /8: 7.8 kHz PWM */
    OCR1A = 1999;       /* 1 ms at /8 */
    TCCR1A = 0;
    TCCR1B = _BV(WGM12) | _BV(CS11);
    TIMSK1 = _BV(OCIE1A);
    UCSR0A = _BV(U2X0);
    UBRR0 = (F_CPU / 8 / 115200UL) - 1;
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
    sei();
    ready();
    for (;;) {
        wdt_reset();
        if (timed_out) {
            timed_out = 0;
            fail(PSTR("host silent: laser off until reset"));
        }
        if (uart_error) {
            uart_error = 0;
            n = 0;
            fail(PSTR("serial error (a byte lost): laser off until reset"));
        }
        if (head == tail) continue;
        got[n++] = ring[tail & (RING - 1)];
        tail++;
        if (n == 3) {
            n = 0;
            frame(got[0], got[1], got[2]);
        }
    }
}
