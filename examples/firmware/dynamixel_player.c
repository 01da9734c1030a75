/*
 * dynamixel_player.c - the ESPE laser engraver: Dynamixel AX servos on a half-duplex bus and the
 * laser's PWM pin, from a deltaslice stream. Built for the host, it writes what the controller
 * would put on the bus and the laser pin, one line each:
 *
 *     dynamixel_player STREAM.dsl [--baud B] [--ids 1,2,3]
 *
 *     T <id> <hex bytes>              torque enable, once per servo before the first sample
 *     P <sample> <hex bytes>          a SYNC_WRITE of the joints' goal positions
 *     L <sample> <duty 0..255>        the laser's PWM duty, whenever it changes
 *     M <sample> <mode>               a laser mode event (0 off, 3 constant, 4 dynamic)
 *     # decimation <k> packet <bytes> B <us> us
 *
 * The joint counts are AX goal positions (the printer file: zero_count 512 at 150 deg of the
 * servo, counts_per_unit 1024/300 per deg). One SYNC_WRITE takes 8 + 3 x servos bytes; when that
 * is longer on the bus than a sample period, every k-th sample is sent (k = the smallest whole
 * number of periods the packet fits in) and the last sample always, so the servos end exactly
 * where the stream ends. The laser follows every sample: its power is the tool channel's count
 * (power_counts = 255: the 8-bit PWM duty), off whenever the laser mode is off (M5).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "dsl_file.h"
#include "dsl_player.h"
#include "dynamixel.h"

static dsl_player player;

static void hex(const uint8_t *b, size_t n)
{
    size_t k;
    for (k = 0; k < n; k++) printf(" %02X", b[k]);
    putchar('\n');
}

int main(int argc, char **argv)
{
    const char *path = NULL;
    uint32_t baud = 1000000, period_us, k_dec = 1, n_samples = 0;
    uint8_t ids[DXL_MAX_SERVOS] = {1, 2, 3, 4, 5, 6, 7, 8}, packet[DXL_MAX_PACKET], joints = 0, torque_sent = 0;
    uint8_t laser_mode = 4; /* a stream without laser events fires as its tool channel says */
    int32_t counts[DSL_MAX_CHANNELS], last[DSL_MAX_CHANNELS], duty = -1;
    static dsl_file input;
    size_t len;
    int a, have_last = 0;

    for (a = 1; a < argc; a++) {
        if (!strcmp(argv[a], "--baud") && a + 1 < argc) {
            baud = (uint32_t)strtoul(argv[++a], NULL, 10);
        } else if (!strcmp(argv[a], "--ids") && a + 1 < argc) {
            char *s = argv[++a];
            uint8_t n = 0;
            while (*s && n < DXL_MAX_SERVOS) {
                ids[n++] = (uint8_t)strtoul(s, &s, 10);
                if (*s == ',') s++;
            }
        } else if (!path) {
            path = argv[a];
        } else {
            path = NULL;
            break;
        }
    }
    if (!path || baud == 0) {
        fprintf(stderr, "usage: %s STREAM.dsl [--baud B] [--ids 1,2,3]\n", argv[0]);
        return 2;
    }
    if (dsl_file_start(&player, &input, path, 4096) != 0) return 2;
    for (;;) {
        int r, status;
        while ((r = dsl_next(&player, counts)) == DSL_SAMPLE || r == DSL_EVENT) {
            uint32_t i = player.sample_index - 1;
            int32_t want;
            if (r == DSL_EVENT) {
                if (player.event_kind == DSL_EV_LASER_MODE) {
                    laser_mode = (uint8_t)player.event_value;
                    printf("M %lu %u\n", (unsigned long)player.event_index, laser_mode);
                }
                continue;
            }
            if (!torque_sent) {
                uint8_t one = 1, s;
                size_t plen;
                joints = (uint8_t)(player.n_channels - 1);
                if (joints > DXL_MAX_SERVOS) joints = DXL_MAX_SERVOS;
                period_us = (uint32_t)(1000000000ull / player.rate_mhz);
                plen = 8u + 3u * joints;
                k_dec = (dxl_packet_us(plen, baud) + period_us - 1) / period_us;
                if (k_dec < 1) k_dec = 1;
                printf("# decimation %lu packet %lu B %lu us\n", (unsigned long)k_dec, (unsigned long)plen,
                       (unsigned long)dxl_packet_us(plen, baud));
                for (s = 0; s < joints; s++) {
                    len = dxl_write(packet, ids[s], DXL_TORQUE_ENABLE, &one, 1);
                    printf("T %u", ids[s]);
                    hex(packet, len);
                }
                torque_sent = 1;
            }
            if (i % k_dec == 0) {
                len = dxl_sync_write_u16(packet, DXL_GOAL_POSITION, ids, counts, joints);
                printf("P %lu", (unsigned long)i);
                hex(packet, len);
                have_last = 0;
            } else {
                memcpy(last, counts, sizeof last);
                have_last = 1;
            }
            want = laser_mode ? counts[joints] : 0;
            want = want < 0 ? 0 : want > 255 ? 255 : want;
            if (want != duty) {
                duty = want;
                printf("L %lu %ld\n", (unsigned long)i, (long)duty);
            }
            n_samples = i + 1;
        }
        status = dsl_file_continue(&player, &input, r, path);
        if (status == 0) break;
        if (status != DSL_FILE_MORE) return status;
    }
    if (have_last) { /* the last sample always goes out */
        len = dxl_sync_write_u16(packet, DXL_GOAL_POSITION, ids, last, joints);
        printf("P %lu", (unsigned long)(n_samples - 1));
        hex(packet, len);
    }
    dsl_file_close(&input);
    return 0;
}
