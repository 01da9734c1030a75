/*
 * m0_board.h - what m0_pid_player.c needs of a Cortex-M0 board: the stream's UART, one
 * quadrature counter and one PWM + direction output per motor, the 1 kHz sample tick.
 * m0_board_microbit.c is the board QEMU emulates (`qemu-system-arm -M microbit`, an nRF51) with
 * simulated motors; a PSoC 4 board file maps the same calls to PSoC Creator's components
 * (docs/bring-up.md, "UADY").
 */
#ifndef M0_BOARD_H
#define M0_BOARD_H

#include <stdint.h>

void board_init(void);
int board_uart_read(uint8_t *b);             /* 1 and the byte if one was received, else 0 */
void board_uart_write(uint8_t b);
int32_t board_encoder(int joint);            /* the joint's quadrature count, zeroed at power-up */
void board_motor(int joint, int32_t duty);   /* -255..255: PWM duty, the sign is the direction */
void board_wait_sample(uint32_t period_us);  /* until the next sample tick */
int board_tick_missed(void);                 /* a tick came while no sample was ready (the bytes are late) */
uint32_t board_ms(void);                     /* milliseconds since power-up (wrapping) */
void board_log(const char *line);            /* a line for the developer (not the stream's UART) */
void board_exit(int failed);                 /* the motors are off: halt here */

#endif
