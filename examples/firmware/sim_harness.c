/*
 * sim_harness.c - run an AVR player in simavr (libsimavr), feed it a stream over its UART with
 * the credit flow control of avr_serial.h, and print what its pins did:
 *
 *   sim_harness atmega328p|atmega2560 PLAYER.elf STREAM.dsl [--seconds S]
 *
 *   P <pin> <rise_cycle> <width_cycles>     every pulse of a watched pin (16 cycles = 1 us)
 *   T <sample> <cycle> <pos1> <pos2> <pos3> <pos4>  the step positions at each sample strobe (Mega)
 *   S <sample> <cycle>                      each sample the Uno plays (its strobe pin)
 *   F <pos1> <pos2> <pos3> <pos4>           the step positions at the end (Mega)
 *   L <line>                                a line the board sent ("OK n" or "ERR ...")
 *
 * Uno pins watched: the servos D3, D5, D6 as pins 0..2, the sample strobe D13 (B5). Mega: RAMPS step pins counted
 * with their dir pins. (No thermal model: simavr 1.6 keeps analog inputs for ADC0..7 only, and
 * the RAMPS thermistors are on A13 and A14.)
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <simavr/avr_ioport.h>
#include <simavr/avr_uart.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_elf.h>

static avr_t *avr;
static unsigned char *stream;
static size_t stream_len, sent, allowed;
static int xoff, done;
static char line[256];
static size_t line_len;

static void feed(void)
{
    avr_irq_t *in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    while (!xoff && sent < allowed && sent < stream_len) avr_raise_irq(in, stream[sent++]);
}

static void uart_out(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    if (value == '>' && line_len == 0) {
        allowed += 64;
        feed();
        return;
    }
    if (value == '\n') {
        line[line_len] = 0;
        printf("L %s\n", line);
        line_len = 0;
        done = 1;
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

/* --- pulses (Uno servos) --- */
static uint64_t rise[3];
static int level[3];

static void servo_pin(avr_irq_t *irq, uint32_t value, void *param)
{
    int k = (int)(intptr_t)param;
    (void)irq;
    if (value && !level[k]) rise[k] = avr->cycle;
    if (!value && level[k]) printf("P %d %llu %llu\n", k, (unsigned long long)rise[k], (unsigned long long)(avr->cycle - rise[k]));
    level[k] = value != 0;
}

static long uno_strobes;

static int uno_strobe_level;

static void uno_strobe(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    if ((value != 0) == uno_strobe_level) return; /* not a toggle (the pin being configured) */
    uno_strobe_level = value != 0;
    printf("S %ld %llu\n", uno_strobes++, (unsigned long long)avr->cycle);
}

/* --- steps (Mega) --- */
static long pos[4];
static int dir[4], step_level[4];
static long strobes;

static void step_pin(avr_irq_t *irq, uint32_t value, void *param)
{
    int k = (int)(intptr_t)param;
    (void)irq;
    if (value && !step_level[k]) pos[k] += dir[k] ? 1 : -1;
    step_level[k] = value != 0;
}

static void dir_pin(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    dir[(int)(intptr_t)param] = value != 0;
}

static int strobe_level;

static void strobe(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    if ((value != 0) == strobe_level) return;
    strobe_level = value != 0;
    printf("T %ld %llu %ld %ld %ld %ld\n", strobes++, (unsigned long long)avr->cycle, pos[0], pos[1], pos[2], pos[3]);
}

static void watch(char port, int bit, avr_irq_notify_t fn, int param)
{
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(port), bit), fn, (void *)(intptr_t)param);
}

int main(int argc, char **argv)
{
    elf_firmware_t fw;
    FILE *f;
    double seconds = 60.0;
    int a, mega, state = cpu_Running;

    if (argc < 4) {
        fprintf(stderr, "usage: %s atmega328p|atmega2560 PLAYER.elf STREAM.dsl [--seconds S]\n", argv[0]);
        return 2;
    }
    for (a = 4; a < argc; a++)
        if (!strcmp(argv[a], "--seconds") && a + 1 < argc) seconds = atof(argv[++a]);
    f = fopen(argv[3], "rb");
    if (!f) {
        fprintf(stderr, "error: %s: cannot open\n", argv[3]);
        return 2;
    }
    fseek(f, 0, SEEK_END);
    stream_len = (size_t)ftell(f);
    fseek(f, 0, SEEK_SET);
    stream = malloc(stream_len ? stream_len : 1);
    if (fread(stream, 1, stream_len, f) != stream_len) return 2;
    fclose(f);

    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(argv[2], &fw)) {
        fprintf(stderr, "error: %s: cannot read the ELF\n", argv[2]);
        return 2;
    }
    avr = avr_make_mcu_by_name(argv[1]);
    if (!avr) {
        fprintf(stderr, "error: simavr has no core %s\n", argv[1]);
        return 2;
    }
    avr_init(avr);
    fw.frequency = 16000000;
    avr_load_firmware(avr, &fw);
    avr->frequency = 16000000;
    avr->vcc = avr->avcc = avr->aref = 5000;
    avr->log = 0;

    {   /* the UART: no stdio echo, our callbacks */
        uint32_t flags = 0;
        avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
        flags &= ~AVR_UART_FLAG_STDIO;
        avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_out, NULL);
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), uart_xon, NULL);
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), uart_xoff, NULL);
    }
    mega = !strcmp(argv[1], "atmega2560");
    if (!mega) {
        watch('D', 3, servo_pin, 0);
        watch('D', 5, servo_pin, 1);
        watch('D', 6, servo_pin, 2);
        watch('B', 5, uno_strobe, 0);
    } else {
        watch('F', 0, step_pin, 0); watch('F', 1, dir_pin, 0);
        watch('F', 6, step_pin, 1); watch('F', 7, dir_pin, 1);
        watch('L', 3, step_pin, 2); watch('L', 1, dir_pin, 2);
        watch('A', 4, step_pin, 3); watch('A', 6, dir_pin, 3);
        watch('B', 7, strobe, 0);
    }
    while (state != cpu_Done && state != cpu_Crashed && !done && avr->cycle < (avr_cycle_count_t)(seconds * 16e6))
        state = avr_run(avr);
    if (!done) {
        line[line_len] = 0;
        if (line_len) printf("L %s\n", line);
        printf("L TIMEOUT after %.3f s (%zu of %zu bytes sent, state %d)\n", avr->cycle / 16e6, sent, stream_len, state);
        return 1;
    }
    /* let the last frame finish */
    {
        avr_cycle_count_t end = avr->cycle + 16000 * 45;
        while (state != cpu_Done && state != cpu_Crashed && avr->cycle < end) state = avr_run(avr);
    }
    if (mega) printf("F %ld %ld %ld %ld\n", pos[0], pos[1], pos[2], pos[3]);
    return 0;
}
