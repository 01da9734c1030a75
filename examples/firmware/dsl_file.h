/*
 * dsl_file.h - feeding a player from a file (the host builds; an SD card reader looks the same):
 * read in chunks, offer what the player takes, finish at the end of the file.
 */
#ifndef DSL_FILE_H
#define DSL_FILE_H

#include <stdio.h>

#include "dsl_player.h"

#define DSL_FILE_BUF 65536

typedef struct {
    FILE *f;
    size_t chunk;        /* bytes read at a time (1: byte by byte, as from a UART) */
    size_t avail, off;
    int eof;
    uint8_t buf[DSL_FILE_BUF];
} dsl_file;

static void dsl_file_open(dsl_file *in, FILE *f, size_t chunk)
{
    in->f = f;
    in->chunk = chunk < 1 || chunk > DSL_FILE_BUF ? DSL_FILE_BUF : chunk;
    in->avail = in->off = 0;
    in->eof = 0;
}

/* Give the player more input (call when dsl_next says DSL_AGAIN). 0, or -1 on a read error. */
static int dsl_file_pump(dsl_player *p, dsl_file *in)
{
    if (in->avail == 0 && !in->eof) {
        in->avail = fread(in->buf, 1, in->chunk, in->f);
        in->off = 0;
        if (in->avail == 0) {
            if (ferror(in->f)) return -1;
            in->eof = 1;
        }
    }
    if (in->avail) {
        size_t used = dsl_feed(p, in->buf + in->off, in->avail);
        in->off += used;
        in->avail -= used;
    } else {
        dsl_finish(p);
    }
    return 0;
}

#endif
