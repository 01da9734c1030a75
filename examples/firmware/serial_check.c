/*
 * serial_check.c - avr_serial.h's credit flow control built for the host (host_avr/ stands in for
 * avr-libc; the receive interrupt is a function called per byte) against a host that sends one
 * 64-byte chunk per credit ('>'):
 *
 *     serial_check SEED   prints "second_credit_after <n>": a whole chunk received, the board
 *                         busy (nothing taken), the bytes it must take before the next credit;
 *                         then "bytes <n> max_in_ring <n> lost <n>" for a random schedule of
 *                         arrivals and takes (every byte checked in order: none overwritten)
 */
#include <stdio.h>
#include <stdlib.h>

#define F_CPU 16000000UL
#define USART_RX_vect_NAME usart_rx
#include "avr_serial.h"

uint8_t UDR0, UCSR0B, UCSR0C, SREG;
uint16_t UBRR0;
static uint8_t ucsr0a;
static unsigned long ucsr0a_reads;

uint8_t *host_ucsr0a(void)
{
    ucsr0a_reads++;
    ucsr0a = 0xFF; /* always ready to send */
    return &ucsr0a;
}

static unsigned long credits(void) { return ucsr0a_reads - 1; } /* serial_init wrote it once */

static void rx(uint8_t b)
{
    UDR0 = b;
    usart_rx();
}

/* Stream byte number `sent`, after its chunk's length byte when it opens a chunk. */
static void rx_stream(unsigned long sent)
{
    if (sent % DSL_CHUNK == 0) rx(DSL_CHUNK);
    rx((uint8_t)sent);
}

int main(int argc, char **argv)
{
    unsigned long owed = 0, sent = 0, taken = 0, used, max_used = 0, lost = 0, k, before;
    uint8_t b = 0;
    (void)serial_puts_P; /* the players' lines: not checked here */
    (void)serial_putu;
    srand(argc > 1 ? (unsigned)atoi(argv[1]) : 1);
    serial_init();
    serial_grant();
    owed = credits() * DSL_CHUNK;
    for (; sent < owed; sent++) rx_stream(sent); /* the first chunks arrive whole while the board is busy */
    rx('p'); /* controls between chunks take no ring space and no credit */
    rx('r');
    if (serial_paused || serial_bad || serial_used() != owed) {
        printf("controls between chunks: paused %d bad %d used %u\n", serial_paused, serial_bad, serial_used());
        return 1;
    }
    before = credits();
    for (k = 0; k < DSL_CHUNK; k++) {
        serial_grant();
        if (credits() > before) break;
        serial_take(&b);
        lost += b != (uint8_t)taken++;
    }
    printf("second_credit_after %lu\n", k);
    for (k = 0; k < 1000000UL; k++) {
        owed = credits() * DSL_CHUNK;
        if (sent < owed && rand() % 2) rx_stream(sent++);
        used = sent - taken;
        if (used > max_used) max_used = used;
        if (rand() % 3 == 0 && serial_take(&b)) lost += b != (uint8_t)taken++;
        serial_grant();
    }
    while (serial_take(&b)) lost += b != (uint8_t)taken++;
    lost += taken != sent;
    printf("bytes %lu max_in_ring %lu lost %lu\n", sent, max_used, lost);
    return 0;
}
