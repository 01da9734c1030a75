/*
 * avr_serial.h - the serial side of the AVR players: USART0 at 115200 baud, a receive ring
 * filled by the RX interrupt, and the credit flow control of `deltaslice send`:
 *
 *   board -> host  '>'            one credit: the board has room for one more chunk
 *   host  -> board <= 64 bytes    one chunk per credit (DSL_CHUNK; the last one may be shorter)
 *   board -> host  "OK <n>\n"     the stream ended intact after n samples
 *                  "ERR <msg>\n"  the stream is damaged or meant for another printer; the player stopped
 *                  "# <text>\n"   information outside the protocol ("# heating" once a second while a
 *                                 heater wait holds the stream): the host ignores it, but it is not silence
 *
 * The ring holds two chunks, so the host can send the next chunk while the board decodes the
 * previous one; a credit is sent only for space that is free, so nothing is ever dropped.
 * Strings live in flash (PSTR) to keep static RAM for the record buffers.
 */
#ifndef AVR_SERIAL_H
#define AVR_SERIAL_H

#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/pgmspace.h>
#include <stdint.h>

#define DSL_CHUNK 64
#define SERIAL_RING 128 /* two chunks; a power of two */

static volatile uint8_t serial_ring[SERIAL_RING];
static volatile uint8_t serial_head, serial_tail; /* written by the ISR, read by the main loop */
static uint8_t serial_credits;                    /* chunks promised to the host and not yet received */
static uint8_t serial_chunk_fill;                 /* bytes received of the oldest promised chunk */

ISR(USART_RX_vect_NAME)
{
    uint8_t b = UDR0;
    serial_ring[serial_head] = b;
    serial_head = (uint8_t)((serial_head + 1) & (SERIAL_RING - 1));
}

static void serial_init(void)
{
    UCSR0A = _BV(U2X0);
    UBRR0 = (F_CPU / 8 / 115200UL) - 1; /* 16 MHz: 16 -> 117647 baud (+2.1 %) */
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
}

static void serial_put(uint8_t c)
{
    while (!(UCSR0A & _BV(UDRE0))) {
    }
    UDR0 = c;
}

static void serial_puts_P(const char *s)
{
    char c;
    while ((c = (char)pgm_read_byte(s++)) != 0) serial_put((uint8_t)c);
}

static void serial_putu(uint32_t v)
{
    char d[11];
    uint8_t n = 0;
    do {
        d[n++] = (char)('0' + v % 10);
        v /= 10;
    } while (v);
    while (n) serial_put((uint8_t)d[--n]);
}

static uint8_t serial_used(void)
{
    return (uint8_t)((serial_head - serial_tail) & (SERIAL_RING - 1));
}

/* Grant credits for the ring space no promised chunk will fill. */
static void serial_grant(void)
{
    uint8_t used = serial_used();
    uint16_t promised = (uint16_t)serial_credits * DSL_CHUNK - serial_chunk_fill;
    while ((uint16_t)used + promised + DSL_CHUNK <= SERIAL_RING - 1) {
        serial_put('>');
        serial_credits++;
        promised += DSL_CHUNK;
    }
}

/* Take one received byte; 0 when there is none. */
static uint8_t serial_take(uint8_t *b)
{
    if (serial_head == serial_tail) return 0;
    *b = serial_ring[serial_tail];
    serial_tail = (uint8_t)((serial_tail + 1) & (SERIAL_RING - 1));
    if (serial_credits && ++serial_chunk_fill == DSL_CHUNK) {
        serial_credits--;
        serial_chunk_fill = 0;
    }
    return 1;
}

/* The player's last line: "ERR <message in flash>", "ERR <error in RAM>" or "OK <samples>". */
static void serial_verdict(const char *message_P, const char *error, uint32_t samples)
{
    if (message_P || (error && *error)) {
        serial_puts_P(PSTR("ERR "));
        if (message_P) serial_puts_P(message_P);
        else while (*error) serial_put((uint8_t)*error++);
    } else {
        serial_puts_P(PSTR("OK "));
        serial_putu(samples);
    }
    serial_put('\n');
}

#endif
