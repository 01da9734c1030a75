/* host_avr/avr/io.h - just enough of avr-libc's names to build avr_serial.h on a PC
   (serial_check.c). Every access to UCSR0A goes through host_ucsr0a(), which counts them: the
   serial_put() of one byte reads it once. */
#ifndef HOST_AVR_IO_H
#define HOST_AVR_IO_H
#include <stdint.h>
#define _BV(b) (1u << (b))
extern uint8_t UDR0, UCSR0B, UCSR0C, SREG;
extern uint16_t UBRR0;
uint8_t *host_ucsr0a(void);
#define UCSR0A (*host_ucsr0a())
#define U2X0 1
#define UDRE0 5
#define RXCIE0 7
#define RXEN0 4
#define TXEN0 3
#define UCSZ01 2
#define UCSZ00 1
#endif
