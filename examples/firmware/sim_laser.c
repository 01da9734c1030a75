/*
 * sim_laser.c - run uno_laser_player in simavr: send it bytes over its UART at scheduled times
 * (what `deltaslice play --laser` would send) and measure the laser pin's duty:
 *
 *   sim_laser PLAYER.elf SCRIPT [--seconds S]
 *
 *   SCRIPT: one line per write, "<ms> <hex bytes>", the bytes go out at that simulated time
 *
 *   D <window> <high cycles>   the time D11 (PB3) was high in each window of 16,384 cycles
 *                              (1.024 ms: exactly 8 periods of the 7.8 kHz PWM, so a duty d
 *                              held over a window reads 64 x d cycles whatever its phase)
 *   L <cycle> <line>           a line the board sent
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <simavr/avr_ioport.h>
#include <simavr/avr_uart.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_cycle_timers.h>
#include <simavr/sim_elf.h>

#define WINDOW 16384ull
#define CYCLES_PER_MS 16000ull

static avr_t *avr;
static char line[256];
static size_t line_len;

typedef struct {
    unsigned long long cycle;
    unsigned char bytes[64];
    int n;
} write_t;

static write_t *writes;
static int n_writes, next_write;
static unsigned char pending[4096];
static int pending_n, pending_at, xoff;

static void feed(void)
{
    avr_irq_t *in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    while (!xoff && pending_at < pending_n) avr_raise_irq(in, pending[pending_at++]);
    if (pending_at == pending_n) pending_at = pending_n = 0;
}

static avr_cycle_count_t send_due(avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a;
    (void)param;
    while (next_write < n_writes && writes[next_write].cycle <= when) {
        write_t *w = &writes[next_write++];
        if (pending_n + w->n <= (int)sizeof pending) {
            memcpy(pending + pending_n, w->bytes, (size_t)w->n);
            pending_n += w->n;
        }
    }
    feed();
    return next_write < n_writes ? writes[next_write].cycle : 0;
}

static void uart_out(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    if (value == '\n') {
        line[line_len] = 0;
        printf("L %llu %s\n", (unsigned long long)avr->cycle, line);
        line_len = 0;
    } else if (line_len < sizeof line - 1) {
        line[line_len++] = (char)value;
    }
}

static void uart_xon(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)value; (void)param;
    xoff = 0;
    feed();
}

static void uart_xoff(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)value; (void)param;
    xoff = 1;
}

/* --- the laser pin's high time per window --- */
static int level;
static unsigned long long since, high;

static void account(unsigned long long to)
{
    while (since < to) {
        unsigned long long end = (since / WINDOW + 1) * WINDOW, seg = to < end ? to : end;
        if (level) high += seg - since;
        since = seg;
        if (seg == end) {
            printf("D %llu %llu\n", end / WINDOW - 1, high);
            high = 0;
        }
    }
}

static void laser_pin(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    account(avr->cycle);
    level = value != 0;
}

static int read_script(const char *path)
{
    FILE *f = fopen(path, "r");
    char buf[512];
    int cap = 0;
    if (!f) return -1;
    while (fgets(buf, sizeof buf, f)) {
        char *s = buf;
        double ms = strtod(s, &s);
        write_t w;
        if (s == buf) continue;
        w.cycle = (unsigned long long)(ms * CYCLES_PER_MS);
        w.n = 0;
        for (;;) {
            char *e;
            unsigned long v = strtoul(s, &e, 16);
            if (e == s || w.n == (int)sizeof w.bytes) break;
            w.bytes[w.n++] = (unsigned char)v;
            s = e;
        }
        if (n_writes == cap) {
            cap = cap ? 2 * cap : 256;
            writes = realloc(writes, (size_t)cap * sizeof *writes);
            if (!writes) return -1;
        }
        writes[n_writes++] = w;
    }
    fclose(f);
    return 0;
}

int main(int argc, char **argv)
{
    elf_firmware_t fw;
    double seconds = 10.0;
    int state = cpu_Running;

    if (argc < 3) {
        fprintf(stderr, "usage: %s PLAYER.elf SCRIPT [--seconds S]\n", argv[0]);
        return 2;
    }
    if (argc == 5 && !strcmp(argv[3], "--seconds")) seconds = atof(argv[4]);
    if (read_script(argv[2])) {
        fprintf(stderr, "error: %s: cannot read the script\n", argv[2]);
        return 2;
    }
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(argv[1], &fw)) {
        fprintf(stderr, "error: %s: cannot read the ELF\n", argv[1]);
        return 2;
    }
    avr = avr_make_mcu_by_name("atmega328p");
    avr_init(avr);
    fw.frequency = 16000000;
    avr_load_firmware(avr, &fw);
    avr->frequency = 16000000;
    avr->log = 0;
    {
        uint32_t flags = 0;
        avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
        flags &= ~AVR_UART_FLAG_STDIO;
        avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_out, NULL);
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), uart_xon, NULL);
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), uart_xoff, NULL);
    }
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 3), laser_pin, NULL);
    if (n_writes) avr_cycle_timer_register(avr, writes[0].cycle ? writes[0].cycle : 1, send_due, NULL);
    while (state != cpu_Done && state != cpu_Crashed && avr->cycle < (avr_cycle_count_t)(seconds * 16e6))
        state = avr_run(avr);
    account(avr->cycle / WINDOW * WINDOW);
    return state == cpu_Crashed ? 1 : 0;
}
