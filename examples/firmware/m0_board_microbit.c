/*
 * m0_board_microbit.c - m0_board.h on the BBC micro:bit that `qemu-system-arm -M microbit`
 * emulates (nRF51822, a Cortex-M0 at 16 MHz): the stream on the nRF51's UART, the developer's
 * lines through semihosting (QEMU's -semihosting-config enable=on: they reach QEMU's stdout),
 * and in place of the UADY's motors and encoders dc_motor_model.h's simulated gear motors,
 * advanced one sample period at each tick (the simulated time is the model's, so QEMU runs
 * as fast as it can).
 */
#include <stdint.h>

#include "dc_motor_model.h"
#include "m0_board.h"

#define JOINTS 3

/* nRF51 UART registers (nRF51 Series Reference Manual, UART) */
#define UART_BASE 0x40002000u
#define UART_REG(off) (*(volatile uint32_t *)(UART_BASE + (off)))
#define UART_STARTRX UART_REG(0x000)
#define UART_STARTTX UART_REG(0x008)
#define UART_RXDRDY UART_REG(0x108)
#define UART_TXDRDY UART_REG(0x11C)
#define UART_ENABLE UART_REG(0x500)
#define UART_RXD UART_REG(0x518)
#define UART_TXD UART_REG(0x51C)
#define UART_BAUDRATE UART_REG(0x524)
#define UART_BAUD_115200 0x01D7E000u

/* ARM semihosting: the operation in r0, its argument in r1, then BKPT 0xAB (Cortex-M) */
#define SYS_WRITE0 0x04

static int semihost(int op, const void *arg)
{
    register int r0 __asm__("r0") = op;
    register const void *r1 __asm__("r1") = arg;
    __asm__ volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
    return r0;
}

static motor motors[JOINTS];
static int32_t duties[JOINTS];

/* SysTick (the Cortex-M0's own timer) for board_ms: 1 ms at the nRF51's 16 MHz */
#define SYST_CSR (*(volatile uint32_t *)0xE000E010u)
#define SYST_RVR (*(volatile uint32_t *)0xE000E014u)
#define SYST_CVR (*(volatile uint32_t *)0xE000E018u)
#define SYST_COUNTFLAG (1u << 16)

static uint32_t ms;

uint32_t board_ms(void)
{
    if (SYST_CSR & SYST_COUNTFLAG) ms++; /* read often enough (the main loop): a lap lost is no harm */
    return ms;
}

void board_init(void)
{
    SYST_RVR = 16000u - 1u;
    SYST_CVR = 0;
    SYST_CSR = 5u; /* enabled, the processor's clock, no interrupt */
    UART_ENABLE = 4;
    UART_BAUDRATE = UART_BAUD_115200;
    UART_STARTRX = 1;
    UART_STARTTX = 1;
}

int board_uart_read(uint8_t *b)
{
    if (!UART_RXDRDY) return 0;
    UART_RXDRDY = 0; /* cleared before the read: the read sets it again when more bytes wait */
    *b = (uint8_t)UART_RXD;
    return 1;
}

void board_uart_write(uint8_t b)
{
    UART_TXDRDY = 0;
    UART_TXD = b;
    while (!UART_TXDRDY) {
    }
}

int32_t board_encoder(int joint) { return encoder(&motors[joint]); }

void board_motor(int joint, int32_t duty) { duties[joint] = duty; }

void board_wait_sample(uint32_t period_us)
{
    int j;
    for (j = 0; j < JOINTS; j++) motor_run(&motors[j], duties[j], period_us * 1e-6);
}

/* the simulated time is the samples': a tick comes only with a sample */
int board_tick_missed(void) { return 0; }

void board_log(const char *line) { semihost(SYS_WRITE0, line); }

void board_exit(int failed)
{
    /* halt, as the board does: QEMU keeps its socket open, so the host reads the verdict line
       whatever it still had on its way (QEMU leaving with unread bytes would reset the
       connection and could lose the line); the log says how it ended, the host ends QEMU */
    board_log(failed ? "# halted: failed\n" : "# halted: done\n");
    for (;;) __asm__ volatile("wfi");
}

/* start-up: .data from flash, .bss zeroed, then main; the vector table's first two words */
extern uint32_t _data_load, _data_start, _data_end, _bss_start, _bss_end, _stack_top;
int main(void);

void reset_handler(void)
{
    uint32_t *src = &_data_load, *dst = &_data_start;
    while (dst < &_data_end) *dst++ = *src++;
    for (dst = &_bss_start; dst < &_bss_end;) *dst++ = 0;
    board_exit(main() != 0);
}

static void fault_handler(void) { board_exit(1); }

__attribute__((section(".vectors"), used)) static void (*const vectors[16])(void) = {
    (void (*)(void))(uintptr_t)&_stack_top, reset_handler, fault_handler, fault_handler,
};
