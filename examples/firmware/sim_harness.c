/*
 * sim_harness.c - run an AVR player in simavr (libsimavr), feed it a stream over its UART with
 * the credit flow control of avr_serial.h, and print what its pins did:
 *
 *   sim_harness atmega328p|atmega2560 PLAYER.elf STREAM.dsl [--seconds S] [--thermistors H,B]
 *               [--fix-thermistor HEATER,ADC,FROM_S] [--cut BYTES] [--stall BYTES,SECONDS] [--after S]
 *               [--pause AT_S,FOR_S] [--abort AT_S] [--estop AT_S] [--unframed] [--endstops h|l|n<steps> x3]
 *
 *   P <pin> <rise_cycle> <width_cycles>     every pulse of a watched pin (16 cycles = 1 us)
 *   T <sample> <cycle> <pos1> <pos2> <pos3> <pos4>  the step positions at each sample strobe (Mega)
 *   S <sample> <cycle>                      each sample the Uno plays (its strobe pin)
 *   F <pos1> <pos2> <pos3> <pos4>           the step positions at the end (Mega)
 *   L <line>                                the board's verdict line ("OK n" or "ERR ...")
 *   I <cycle> <line>                        an information line ("# ...", e.g. "# heating")
 *   H <heater> <cycle> <level> <temp x10>   a heater pin switched (Mega: 0 hot end D10, 1 bed D8)
 *   K <cycle> <hot end x10> <bed x10>       the model's temperatures every 10 ms (Mega)
 *   N <cycle> <mask>                        the driver enable pins changed: bit a set = axis a
 *                                           disabled (Mega X, Y, Z, E0; Uno: bit 3, the extruder)
 *   X <cycle> <bytes> cut|stall|resume      the sender's injected fault began (or ended)
 *
 * Faults to inject: --fix-thermistor: from FROM_S seconds on, that heater's thermistor reads ADC
 * whatever the model says (1023 an open sensor, 0 a short, ~990 a cold one); --cut: the sender
 * goes silent for good after BYTES bytes; --stall: it stops after BYTES bytes for SECONDS, then
 * goes on. --after: how long to go on simulating after the verdict line (default 0.045 s), to see
 * that nothing switches on again. --pause: the host's feed hold ('p', repeated every second as
 * deltaslice send does) at AT_S for FOR_S, then 'r'; --abort: 'x' at AT_S; --estop: the Mega's
 * E-stop input D41 (held low, the normally closed switch) opens at AT_S; --unframed: the chunks
 * without their length byte (a sender of the protocol before the framing).
 *
 * --endstops: the Mega's end stops, per axis a side and a step position counted from power-up
 * (h300: a max switch tripping at 300 steps and beyond, l-250: a min switch at -250 and below, n:
 * none); a tripped switch reads high (normally closed to GND, open), on the RAMPS pins.
 *
 * The sender frames every chunk with its length and puts the controls between chunks only, as
 * deltaslice send does.
 *
 * Uno pins watched: the servos D3, D5, D6 as pins 0..2, the sample strobe D13 (B5). Mega: RAMPS
 * step pins counted with their dir pins, the heater pins, and a thermal model of each heater:
 *
 *   dT/dt = rate x (heater on) - loss x (T - 25 C)
 *   hot end: rate 50 C/s, loss 0.05 /s;  bed: rate 15 C/s, loss 0.02 /s
 *
 * (far faster than a real machine, so a wait for 200 C takes seconds of simulated time), solved
 * exactly between the pin changes. At every ADC conversion the model's temperatures go to the
 * thermistor inputs as the voltage that reads what dsl_thermistor.h (the player's own table)
 * says for them. simavr 1.6 keeps analog inputs for ADC0..7 only, while the RAMPS thermistors
 * are on A13 and A14: the player's simulated builds (make sim) move them (--thermistors, default
 * 5,6), and a build that converts A8..A15 is refused (exit 3).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <simavr/avr_adc.h>
#include <simavr/avr_ioport.h>
#include <simavr/avr_uart.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_cycle_timers.h>
#include <simavr/sim_elf.h>

#include "dsl_thermistor.h"

static avr_t *avr;
static unsigned char *stream;
static size_t stream_len, sent, allowed;
static int xoff, done;
static char line[256];
static size_t line_len;

static size_t cut_at = (size_t)-1, stall_at = (size_t)-1, chunk_left;
static int unframed;
static char controls[16]; /* waiting for the end of the chunk on the wire */
static int n_controls;
static double stall_seconds;
static int stall_state; /* 0 before, 1 stalled, 2 over */
static avr_cycle_count_t stall_end;

static void feed(void);

static avr_cycle_count_t stall_over(avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a; (void)when; (void)param;
    stall_state = 2;
    printf("X %llu %zu resume\n", (unsigned long long)avr->cycle, sent);
    feed();
    return 0;
}

static void feed(void)
{
    avr_irq_t *in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    while (!xoff && sent < allowed && sent < stream_len) {
        if (sent == cut_at) {
            printf("X %llu %zu cut\n", (unsigned long long)avr->cycle, sent);
            cut_at = (size_t)-1;
            stream_len = sent; /* nothing more, ever */
            return;
        }
        if (sent == stall_at && stall_state == 0) {
            stall_state = 1;
            stall_end = avr->cycle + (avr_cycle_count_t)(stall_seconds * 16e6);
            printf("X %llu %zu stall\n", (unsigned long long)avr->cycle, sent);
            avr_cycle_timer_register(avr, stall_end - avr->cycle, stall_over, NULL);
        }
        if (stall_state == 1) return;
        if (!chunk_left) {
            chunk_left = allowed - sent < 64 ? allowed - sent : 64;
            if (stream_len - sent < chunk_left) chunk_left = stream_len - sent;
            if (!unframed) avr_raise_irq(in, (uint32_t)chunk_left);
        }
        avr_raise_irq(in, stream[sent++]);
        chunk_left--;
    }
    if (!chunk_left && !xoff) { /* between chunks: the controls that were waiting */
        int k;
        for (k = 0; k < n_controls; k++) avr_raise_irq(in, (uint8_t)controls[k]);
        n_controls = 0;
    }
}

static void control(char c)
{
    if (n_controls < (int)sizeof controls) controls[n_controls++] = c;
    feed();
}

/* The Mega's E-stop input D41 (PG0): held low by the closed switch, or open (the pull-up wins). */
static void estop_switch(int open)
{
    avr_ioport_external_t ext = {.name = 'G', .mask = 1, .value = (unsigned)open};
    avr_ioctl(avr, AVR_IOCTL_IOPORT_SET_EXTERNAL('G'), &ext);
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('G'), 0), (uint32_t)open);
}

static double pause_at = -1, pause_for, abort_at = -1, estop_at = -1;

static avr_cycle_count_t host_events(avr_t *a, avr_cycle_count_t when, void *param)
{
    double t = (double)avr->cycle / 16e6;
    (void)a; (void)param;
    if (pause_at >= 0 && t >= pause_at && t < pause_at + pause_for) {
        printf("X %llu %zu pause\n", (unsigned long long)avr->cycle, sent);
        control('p');
        return when + 16000000; /* the feed hold repeated every second: the host is alive */
    }
    if (pause_at >= 0 && t >= pause_at + pause_for) {
        printf("X %llu %zu resume\n", (unsigned long long)avr->cycle, sent);
        control('r');
        pause_at = -1;
    }
    if (abort_at >= 0 && t >= abort_at) {
        printf("X %llu %zu abort\n", (unsigned long long)avr->cycle, sent);
        control('x');
        abort_at = -1;
    }
    if (estop_at >= 0 && t >= estop_at) {
        printf("X %llu %zu estop\n", (unsigned long long)avr->cycle, sent);
        estop_switch(1);
        estop_at = -1;
    }
    {   /* the next event */
        double next = 1e30;
        if (pause_at >= 0) next = pause_at < t ? pause_at + pause_for : pause_at;
        if (abort_at >= 0 && abort_at < next) next = abort_at;
        if (estop_at >= 0 && estop_at < next) next = estop_at;
        return next > 1e29 ? 0 : (avr_cycle_count_t)(next * 16e6) + 1;
    }
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
        if (line[0] == '#') { /* information, not the verdict */
            printf("I %llu %s\n", (unsigned long long)avr->cycle, line);
        } else {
            printf("L %s\n", line);
            done = 1;
        }
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

static int endstop_side[3];
static long endstop_at[3];
static const char endstop_port[3][2] = {{'E', 'E'}, {'J', 'J'}, {'D', 'D'}}; /* [axis][max?] */
static const int endstop_bit[3][2] = {{5, 4}, {1, 0}, {3, 2}};                 /* min, max */

/* Put each axis's switch on its pin (the pull-up's level is what a tripped, open switch reads). */
static void endstops_update(void)
{
    int k;
    for (k = 0; k < 3; k++) {
        int hi = endstop_side[k] > 0, open;
        avr_ioport_external_t ext;
        if (!endstop_side[k]) continue;
        open = hi ? pos[k] >= endstop_at[k] : pos[k] <= endstop_at[k];
        ext.name = endstop_port[k][hi];
        ext.mask = (unsigned)(1 << endstop_bit[k][hi]);
        ext.value = open ? ext.mask : 0;
        avr_ioctl(avr, AVR_IOCTL_IOPORT_SET_EXTERNAL(endstop_port[k][hi]), &ext);
        avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(endstop_port[k][hi]), endstop_bit[k][hi]), (uint32_t)open);
    }
}

static void step_pin(avr_irq_t *irq, uint32_t value, void *param)
{
    int k = (int)(intptr_t)param;
    (void)irq;
    if (value && !step_level[k]) {
        pos[k] += dir[k] ? 1 : -1;
        if (k < 3 && endstop_side[k]) endstops_update();
    }
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

/* --- heaters (Mega): the thermal model --- */
static const double HEAT_RATE[2] = {50.0, 15.0}, HEAT_LOSS[2] = {0.05, 0.02}, AMBIENT = 25.0;
static double temp[2] = {25.0, 25.0};
static int heater_on[2];
static avr_cycle_count_t thermal_cycle;
static int therm_channel[2] = {5, 6};
static int fixed_adc[2] = {-1, -1};
static double fixed_from[2];

/* --- driver enable pins: the mask of disabled axes --- */
static unsigned enable_mask;
static int enable_seen;

static void enable_pin(avr_irq_t *irq, uint32_t value, void *param)
{
    unsigned bit = 1u << (int)(intptr_t)param, mask = value ? enable_mask | bit : enable_mask & ~bit;
    (void)irq;
    if (mask == enable_mask && enable_seen) return;
    enable_mask = mask;
    enable_seen = 1;
    printf("N %llu %u\n", (unsigned long long)avr->cycle, enable_mask);
}

static void thermal_advance(void)
{
    double dt = (double)(avr->cycle - thermal_cycle) / 16e6;
    int h;
    for (h = 0; h < 2; h++) {
        double steady = AMBIENT + HEAT_RATE[h] * heater_on[h] / HEAT_LOSS[h];
        temp[h] = steady + (temp[h] - steady) * exp(-HEAT_LOSS[h] * dt);
    }
    thermal_cycle = avr->cycle;
}

static void heater_pin(avr_irq_t *irq, uint32_t value, void *param)
{
    int h = (int)(intptr_t)param;
    (void)irq;
    if ((value != 0) == heater_on[h]) return;
    thermal_advance();
    heater_on[h] = value != 0;
    printf("H %d %llu %d %ld\n", h, (unsigned long long)avr->cycle, heater_on[h], lround(temp[h] * 10));
}

/* a conversion starts: put the model's temperatures on the thermistor inputs. simavr 1.6 keeps
   ADC0..7 only and reads past that array for A8..A15 (a reading that changes from run to run), so
   a build reading those (the RAMPS's own A13/A14: not `make sim`'s) is refused, not simulated. */
static void adc_trigger(avr_irq_t *irq, uint32_t value, void *param)
{
    union {
        avr_adc_mux_t mux;
        uint32_t v;
    } e = {.v = value};
    int h;
    (void)irq; (void)param;
    if (e.mux.kind == ADC_MUX_SINGLE && e.mux.src >= 8) {
        fprintf(stderr, "error: the player converts ADC%u, which simavr 1.6 does not model (ADC0..7 only): "
                        "run its `make sim` build (thermistors on A5/A6)\n", (unsigned)e.mux.src);
        exit(3);
    }
    thermal_advance();
    for (h = 0; h < 2; h++) {
        uint32_t reading = dsl_ntc_adc_for_celsius_x10((int32_t)lround(temp[h] * 10));
        if (fixed_adc[h] >= 0 && avr->cycle >= fixed_from[h] * 16e6) reading = (uint32_t)fixed_adc[h];
        /* simavr reads millivolts x 1023 / AVCC: the smallest voltage that reads `reading` */
        uint32_t mv = (reading * 5000u + 1022u) / 1023u;
        avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0 + therm_channel[h]), mv);
    }
}

static avr_cycle_count_t thermal_log(avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a; (void)param;
    thermal_advance();
    printf("K %llu %ld %ld\n", (unsigned long long)avr->cycle, lround(temp[0] * 10), lround(temp[1] * 10));
    return when + 160000; /* every 10 ms */
}

static void watch(char port, int bit, avr_irq_notify_t fn, int param)
{
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(port), bit), fn, (void *)(intptr_t)param);
}

int main(int argc, char **argv)
{
    elf_firmware_t fw;
    FILE *f;
    double seconds = 60.0, after = 0.045;
    int a, mega, state = cpu_Running;

    if (argc < 4) {
        fprintf(stderr, "usage: %s atmega328p|atmega2560 PLAYER.elf STREAM.dsl [--seconds S]\n", argv[0]);
        return 2;
    }
    for (a = 4; a < argc; a++)
        if (!strcmp(argv[a], "--seconds") && a + 1 < argc) seconds = atof(argv[++a]);
        else if (!strcmp(argv[a], "--after") && a + 1 < argc) after = atof(argv[++a]);
        else if (!strcmp(argv[a], "--pause") && a + 1 < argc) {
            if (sscanf(argv[++a], "%lf,%lf", &pause_at, &pause_for) != 2) {
                fprintf(stderr, "error: --pause takes AT_SECONDS,FOR_SECONDS\n");
                return 2;
            }
        } else if (!strcmp(argv[a], "--abort") && a + 1 < argc) abort_at = atof(argv[++a]);
        else if (!strcmp(argv[a], "--estop") && a + 1 < argc) estop_at = atof(argv[++a]);
        else if (!strcmp(argv[a], "--unframed")) unframed = 1;
        else if (!strcmp(argv[a], "--endstops") && a + 1 < argc) {
            const char *q = argv[++a];
            int k;
            for (k = 0; k < 3; k++) { /* h<pos>: a max switch, l<pos>: a min switch, n: none */
                char *end;
                endstop_side[k] = *q == 'h' ? 1 : *q == 'l' ? -1 : 0;
                endstop_at[k] = strtol(q + 1, &end, 10);
                if ((*q != 'h' && *q != 'l' && *q != 'n') || (k < 2 && *end != ',')) {
                    fprintf(stderr, "error: --endstops takes three of h<steps> (max switch), l<steps> (min), n (none)\n");
                    return 2;
                }
                q = end + 1;
            }
        }
        else if (!strcmp(argv[a], "--cut") && a + 1 < argc) cut_at = (size_t)atol(argv[++a]);
        else if (!strcmp(argv[a], "--stall") && a + 1 < argc) {
            long at;
            if (sscanf(argv[++a], "%ld,%lf", &at, &stall_seconds) != 2 || at < 0) {
                fprintf(stderr, "error: --stall takes BYTES,SECONDS\n");
                return 2;
            }
            stall_at = (size_t)at;
        } else if (!strcmp(argv[a], "--fix-thermistor") && a + 1 < argc) {
            int h, adc;
            double from;
            if (sscanf(argv[++a], "%d,%d,%lf", &h, &adc, &from) != 3 || h < 0 || h > 1 || adc < 0 || adc > 1023) {
                fprintf(stderr, "error: --fix-thermistor takes HEATER (0 hot end, 1 bed),ADC (0..1023),FROM_SECONDS\n");
                return 2;
            }
            fixed_adc[h] = adc;
            fixed_from[h] = from;
        } else if (!strcmp(argv[a], "--thermistors") && a + 1 < argc) {
            if (sscanf(argv[++a], "%d,%d", &therm_channel[0], &therm_channel[1]) != 2 || therm_channel[0] < 0 ||
                therm_channel[0] > 7 || therm_channel[1] < 0 || therm_channel[1] > 7) {
                fprintf(stderr, "error: --thermistors takes two ADC channels 0..7 (simavr keeps no others)\n");
                return 2;
            }
        }
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
        watch('B', 0, enable_pin, 3);
    } else {
        watch('D', 7, enable_pin, 0);
        watch('F', 2, enable_pin, 1);
        watch('K', 0, enable_pin, 2);
        watch('A', 2, enable_pin, 3);
        watch('F', 0, step_pin, 0); watch('F', 1, dir_pin, 0);
        watch('F', 6, step_pin, 1); watch('F', 7, dir_pin, 1);
        watch('L', 3, step_pin, 2); watch('L', 1, dir_pin, 2);
        watch('A', 4, step_pin, 3); watch('A', 6, dir_pin, 3);
        watch('B', 7, strobe, 0);
        watch('B', 4, heater_pin, 0);
        watch('H', 5, heater_pin, 1);
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_OUT_TRIGGER), adc_trigger, NULL);
        avr_cycle_timer_register(avr, 160000, thermal_log, NULL);
        estop_switch(0);
        endstops_update();
    }
    if (pause_at >= 0 || abort_at >= 0 || estop_at >= 0) {
        double first = pause_at >= 0 ? pause_at : 1e30;
        if (abort_at >= 0 && abort_at < first) first = abort_at;
        if (estop_at >= 0 && estop_at < first) first = estop_at;
        avr_cycle_timer_register(avr, (avr_cycle_count_t)(first * 16e6) + 1, host_events, NULL);
    }
    while (state != cpu_Done && state != cpu_Crashed && !done && avr->cycle < (avr_cycle_count_t)(seconds * 16e6))
        state = avr_run(avr);
    if (!done) {
        line[line_len] = 0;
        if (line_len) printf("L %s\n", line);
        printf("L TIMEOUT after %.3f s (%zu of %zu bytes sent, state %d)\n", avr->cycle / 16e6, sent, stream_len, state);
        return 1;
    }
    /* let the last frame finish, and see what the board does after its verdict */
    {
        avr_cycle_count_t end = avr->cycle + (avr_cycle_count_t)(after * 16e6);
        while (state != cpu_Done && state != cpu_Crashed && avr->cycle < end) state = avr_run(avr);
    }
    if (mega) printf("F %ld %ld %ld %ld\n", pos[0], pos[1], pos[2], pos[3]);
    return 0;
}
