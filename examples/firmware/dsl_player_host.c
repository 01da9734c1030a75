/*
 * dsl_player_host.c - decode a deltaslice stream on a PC with the firmware's player.
 *
 *     cc -std=c99 -O2 -Wall -o dsl_player_host dsl_player_host.c
 *     ./dsl_player_host part.dsl [--chunk N] [--buffers]   (or - for stdin)
 *
 * Prints exactly what `deltaslice decode part.dsl` prints: one line per sample,
 * "index c1 ... cC", and "# event i=<index> kind=<name> value=<value>" before the sample an
 * event record precedes. On a corrupt or truncated stream it prints the samples of the
 * intact blocks before the damage, then a message on stderr, and exits 1
 * (2: usage or I/O error). --chunk N feeds the player N bytes at a time (default
 * 4096; 1 = byte by byte, as from a serial port).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "dsl_file.h"
#include "dsl_player.h"

static const char *const event_names[] = {"", "hotend_set", "hotend_wait", "bed_set", "bed_wait", "fan", "laser_mode"};

static dsl_player player; /* static: ~600 bytes, as it would be in firmware */

int main(int argc, char **argv)
{
    const char *path = NULL;
    size_t chunk = 4096;
    static dsl_file input;
    int a;

    for (a = 1; a < argc; a++) {
        if (strcmp(argv[a], "--chunk") == 0 && a + 1 < argc) {
            chunk = (size_t)strtoul(argv[++a], NULL, 10);
        } else if (!path) {
            path = argv[a];
        } else {
            path = NULL;
            break;
        }
    }
    if (!path) {
        fprintf(stderr, "usage: %s STREAM.dsl [--chunk N]\n", argv[0]);
        return 2;
    }
    if (dsl_file_start(&player, &input, path, chunk) != 0) return 2;
    for (;;) {
        int32_t counts[DSL_MAX_CHANNELS];
        int r, c, status;
        while ((r = dsl_next(&player, counts)) == DSL_SAMPLE || r == DSL_EVENT) {
            if (r == DSL_EVENT) {
                int k = player.event_kind;
                int temperature = k <= DSL_EV_BED_WAIT;
                printf("# event i=%lu kind=%s value=%.10g\n", (unsigned long)player.event_index, event_names[k],
                       temperature ? player.event_value / 10.0 : (double)player.event_value);
                continue;
            }
            printf("%lu", (unsigned long)(player.sample_index - 1));
            for (c = 0; c < player.n_channels; c++) printf(" %ld", (long)counts[c]);
            putchar('\n');
        }
        status = dsl_file_continue(&player, &input, r, path);
        if (status == 0) break;
        if (status != DSL_FILE_MORE) return status;
    }
    dsl_file_close(&input);
    return 0;
}
