/*
 * m0_pid_player.c - the UADY delta on a Cortex-M0 (its PSoC 4; in QEMU the micro:bit's nRF51):
 * the stream arrives over a UART with the credit flow control of `deltaslice send`
 * (examples/firmware/README.md, "Serial protocol"), and at every sample dc_pid.h's position
 * loop drives each DC gear motor to the sample's counts, read back from its quadrature counter.
 *
 * The board's side (UART, counters, PWM, the 1 kHz tick) is m0_board.h's; the setpoints are the
 * stream's counts relative to its first sample, the rest pose, where the counters are zeroed at
 * power-up. Every sample played writes a line to the developer's console (board_log):
 *
 *     <sample> <setpoint 1> <count 1> <duty 1> <setpoint 2> ...   as dc_pid_player.c prints
 *
 * and the board answers the host "OK <samples>" or "ERR <message>" as the AVR players do; the
 * motors are off before either. Build: make -C examples/firmware m0 (arm-none-eabi-gcc).
 */
#include <stdint.h>

#define DSL_BUFFERS 2
#include "dsl_player.h"
#include DSL_CONFIG
#include "dc_pid.h"
#include "m0_board.h"

#define JOINTS 3
#define CHUNK 64  /* bytes the host sends per credit */
#define RING 256  /* a power of two; holds RING - 1 bytes: two chunks more than the credits need */
#define RECREDIT_MS 500 /* the first credit again, while no byte came */

static dsl_player player;
static uint8_t ring[RING];
static uint32_t head, tail;       /* bytes put into and taken from the ring */
static uint32_t received, granted; /* stream bytes received and credited, since power-up */
static uint32_t heard;             /* any byte at all, framing and controls included */
static uint8_t chunk_left;         /* stream bytes still to come in this chunk */
static uint8_t paused, aborted, bad; /* the host's 'p' (until 'r') and 'x'; a byte outside a chunk */

static void serial_puts(const char *s)
{
    while (*s) board_uart_write((uint8_t)*s++);
}

/* Move what the UART holds into the ring, the framing taken off (examples/firmware/README.md,
   "Serial protocol": a length byte before each chunk, 'p' 'r' 'x' between chunks); the credits
   keep the ring from overflowing. */
static void serial_poll(void)
{
    uint8_t b;
    while (head - tail < RING - 1 && board_uart_read(&b)) {
        heard++;
        if (chunk_left) {
            chunk_left--;
            ring[head % RING] = b;
            head++;
            received++;
        } else if (b >= 1 && b <= CHUNK) {
            chunk_left = b;
        } else if (b == 'p') {
            paused = 1;
        } else if (b == 'r') {
            paused = 0;
        } else if (b == 'x') {
            aborted = 1;
        } else if (!bad) {
            bad = b ? b : 0xFF;
        }
    }
}

/* A credit for every chunk of ring space that no received byte fills and no credited byte on
   its way will fill (the host's chunks may end short of a credit: none are owed then). */
static void serial_grant(void)
{
    if ((int32_t)(granted - received) < 0) granted = received;
    while ((head - tail) + (granted - received) + CHUNK <= RING / 2 - 1) {
        board_uart_write('>');
        granted += CHUNK;
    }
}

/* A board that does not reset when the host opens its port (a Bluetooth link, QEMU's socket) sent
   its first credit before anyone listened, or the host's port flushed it on opening: until the
   first byte comes, the first credit goes again every RECREDIT_MS. A host that took two of them
   sends two chunks: the ring's other half holds the second. */
static void serial_recredit(void)
{
    static uint32_t last;
    if (heard || board_ms() - last < RECREDIT_MS) return;
    last = board_ms();
    board_uart_write('>');
}

static char *put_int(char *s, int32_t v)
{
    char d[11];
    int n = 0;
    uint32_t u = v < 0 ? 0u - (uint32_t)v : (uint32_t)v;
    if (v < 0) *s++ = '-';
    do {
        d[n++] = (char)('0' + u % 10u);
        u /= 10u;
    } while (u);
    while (n) *s++ = d[--n];
    return s;
}

static uint32_t held; /* control periods run on the last setpoints while the bytes were late */

static void stop(const char *message)
{
    char line[16];
    int j;
    for (j = 0; j < JOINTS; j++) board_motor(j, 0);
    if (message || player.rx_state == DSL_S_ERROR) {
        serial_puts("ERR ");
        serial_puts(message ? message : player.error);
        serial_puts("\n");
        board_log("# stopped: ");
        board_log(message ? message : player.error);
        board_log("\n");
        board_exit(1);
    }
    board_log("# held ");
    *put_int(line, (int32_t)held) = 0;
    board_log(line);
    board_log(" periods (late bytes)\n");
    *put_int(line, (int32_t)player.sample_index) = 0;
    serial_puts("OK ");
    serial_puts(line);
    serial_puts("\n");
    board_exit(0);
}

static dc_pid pid[JOINTS];
static int32_t setpoint[JOINTS];
static uint32_t period_us = 1000;

/* One control period at the next tick: each joint's PID from its setpoint and its counter. */
static char *control(char *s)
{
    int j;
    board_wait_sample(period_us);
    for (j = 0; j < JOINTS; j++) {
        int32_t pos = board_encoder(j), duty = dc_pid_step(&pid[j], setpoint[j], pos);
        board_motor(j, duty);
        *s++ = ' ';
        s = put_int(s, setpoint[j]);
        *s++ = ' ';
        s = put_int(s, pos);
        *s++ = ' ';
        s = put_int(s, duty);
    }
    return s;
}

int main(void)
{
    int32_t counts[DSL_MAX_CHANNELS], origin[JOINTS];
    dc_pid_gains gains = DC_PID_UADY_GAINS;
    int started = 0, j;
    char line[16 + 3 * JOINTS * 13], *s;

    board_init();
    dsl_init(&player);
    for (;;) {
        int r, budget;
        serial_poll();
        if (aborted) stop("aborted by the host");
        if (bad) stop("serial: a byte outside a chunk (a sender of the unframed protocol?)");
        serial_grant();
        serial_recredit();
        for (budget = 64; budget && tail != head; budget--) {
            if (dsl_feed(&player, &ring[tail % RING], 1) != 1) break;
            tail++;
        }
        if (!started) {
            if (player.rx_state == DSL_S_ERROR) stop(0);
            if (!player.header_ok) continue;
            if (player.fingerprint != DSL_CFG_FINGERPRINT) stop("stream made for another printer (fingerprint)");
            if (player.n_channels - 1 != JOINTS) stop("not a three-joint stream");
            if (player.q_count < DSL_BUFFERS && player.rx_state != DSL_S_END) continue; /* both buffers first */
            period_us = (uint32_t)(1000000000ull / player.rate_mhz);
            started = 1;
        }
        if (paused && player.sample_index) {
            /* the host's feed hold: the last setpoints held, the loop closed, until 'r' */
            control(line);
            continue;
        }
        r = dsl_next(&player, counts);
        if (r == DSL_DONE || r == DSL_ERROR) stop(0);
        if (r == DSL_AGAIN && player.sample_index && board_tick_missed()) {
            /* the bytes are late and a tick has come: hold the last setpoints, the loop closed */
            control(line);
            held++;
            continue;
        }
        if (r != DSL_SAMPLE) continue; /* DSL_EVENT: no heaters on this machine; DSL_AGAIN: more bytes */
        if (player.sample_index == 1) {
            /* the first sample is the rest pose, where the counters were zeroed */
            for (j = 0; j < JOINTS; j++) {
                origin[j] = counts[j];
                dc_pid_init(&pid[j], gains);
            }
        }
        for (j = 0; j < JOINTS; j++) setpoint[j] = counts[j] - origin[j];
        s = control(put_int(line, (int32_t)(player.sample_index - 1)));
        *s++ = '\n';
        *s = 0;
        board_log(line);
    }
}
