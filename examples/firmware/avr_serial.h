/*
 * avr_serial.h - the serial side of the AVR players: USART0 at 115200 baud, a receive ring
 * filled by the RX interrupt, and the credit flow control of `deltaslice send`:
 *
 *   board -> host  '>'            one credit: the board has room for one more chunk
 *   host  -> board n, n bytes     one chunk per credit: its length n (1..DSL_CHUNK, 64; the last one
 *                                 may be shorter), then n bytes of the stream
 *                  'p' 'r' 'x'    between chunks: feed hold (pause; repeated at least once a second
 *                                 while paused, the host's sign of life), resume, abort
 *   board -> host  "OK <n>\n"     the stream ended intact after n samples
 *                  "ERR <msg>\n"  the stream is damaged or meant for another printer; the player stopped
 *                  "# <text>\n"   information outside the protocol ("# heating" once a second while a
 *                                 heater wait holds the stream): the host ignores it, but it is not silence
 *
 * The ring holds 127 bytes (128, one kept empty). A credit goes out whenever the space neither
 * filled nor promised to a chunk on its way is a whole chunk: the first at start, the second as
 * soon as the board has taken the first byte of the first chunk, and so on, so the next chunk is
 * on the wire while the board decodes the one before; nothing is ever dropped.
 * The RX interrupt takes the framing off: only stream bytes reach the ring (and count for the
 * credits); the controls set flags at once, however full the ring. Any other byte between chunks
 * (a host of the unframed protocol before version 2 of it, line noise) is a protocol error.
 * Strings live in flash (PSTR) to keep static RAM for the record buffers.
 */
#ifndef AVR_SERIAL_H
#define AVR_SERIAL_H

#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/pgmspace.h>
#include <stdint.h>

#include "avr_uart.h"

#define DSL_CHUNK 64
#define SERIAL_RING 128 /* a power of two; holds SERIAL_RING - 1 bytes */

static volatile uint8_t serial_ring[SERIAL_RING];
static volatile uint8_t serial_head;     /* written by the ISR */
static uint8_t serial_tail;              /* written by the main loop */
static volatile uint8_t serial_received; /* bytes received, mod 256 (the ISR counts them) */
static uint8_t serial_granted;           /* bytes credited to the host, mod 256 */
static uint8_t serial_chunk_left;        /* stream bytes still to come in this chunk */
static volatile uint8_t serial_heard;    /* any byte at all, controls included, mod 256 */
static volatile uint8_t serial_paused;   /* the host's feed hold: 'p' sets it, 'r' clears it */
static volatile uint8_t serial_abort;    /* 'x' */
static volatile uint8_t serial_bad;      /* a byte outside a chunk that is no control, or 0 */

ISR(USART_RX_vect_NAME)
{
    uint8_t b = UDR0;
    serial_heard++;
    if (serial_chunk_left) {
        serial_chunk_left--;
        serial_ring[serial_head] = b;
        serial_head = (uint8_t)((serial_head + 1) & (SERIAL_RING - 1));
        serial_received++;
    } else if (b >= 1 && b <= DSL_CHUNK) {
        serial_chunk_left = b;
    } else if (b == 'p') {
        serial_paused = 1;
    } else if (b == 'r') {
        serial_paused = 0;
    } else if (b == 'x') {
        serial_abort = 1;
    } else if (!serial_bad) {
        serial_bad = b ? b : 0xFF;
    }
}

static void serial_init(void)
{
    UCSR0A = _BV(U2X0);
    UBRR0 = (F_CPU / 8 / 115200UL) - 1; /* 16 MHz: 16 -> 117647 baud (+2.1 %) */
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
}

static uint8_t serial_used(void)
{
    return (uint8_t)((serial_head - serial_tail) & (SERIAL_RING - 1));
}

/* Grant a credit for every chunk of ring space that no received byte fills and no credited byte
   on its way will fill (a short last chunk leaves its shortfall promised: the stream has ended). */
static void serial_grant(void)
{
    uint8_t used, promised, sreg = SREG;
    cli(); /* the two counts of the same instant */
    used = serial_used();
    promised = (uint8_t)(serial_granted - serial_received);
    SREG = sreg;
    while ((uint16_t)used + promised + DSL_CHUNK <= SERIAL_RING - 1) {
        serial_put('>');
        serial_granted = (uint8_t)(serial_granted + DSL_CHUNK);
        promised = (uint8_t)(promised + DSL_CHUNK);
    }
}

/* Take one received byte; 0 when there is none. */
static uint8_t serial_take(uint8_t *b)
{
    if (serial_head == serial_tail) return 0;
    *b = serial_ring[serial_tail];
    serial_tail = (uint8_t)((serial_tail + 1) & (SERIAL_RING - 1));
    return 1;
}

#endif
