/*
 * avr_uart.h - text out on USART0 for the AVR players (busy-waiting, a byte at a time): the
 * "OK", "ERR" and "#" lines they answer the host with. Strings live in flash (PSTR).
 */
#ifndef AVR_UART_H
#define AVR_UART_H

#include <avr/io.h>
#include <avr/pgmspace.h>
#include <stdint.h>

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

#endif
