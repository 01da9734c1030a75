/*
 * dsl_file.h - feeding a player from a file (the host builds; an SD card reader looks the same):
 * read in chunks, offer what the player takes, finish at the end of the file.
 */
#ifndef DSL_FILE_H
#define DSL_FILE_H

#include <stdio.h>
#include <string.h>

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

/* Open path ("-": standard input) and start a player on it: 0, or -1 after saying why on stderr. */
static int dsl_file_start(dsl_player *p, dsl_file *in, const char *path, size_t chunk)
{
    FILE *f = strcmp(path, "-") == 0 ? stdin : fopen(path, "rb");
    if (!f) {
        fprintf(stderr, "error: %s: cannot open\n", path);
        return -1;
    }
    dsl_init(p);
    dsl_file_open(in, f, chunk);
    return 0;
}

static void dsl_file_close(dsl_file *in)
{
    if (in->f && in->f != stdin) fclose(in->f);
    in->f = NULL;
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

/* The host loop's step after dsl_next gave r, neither a sample nor an event: DSL_FILE_MORE when the
 * player got more input and the loop goes on; otherwise the exit status, 0 at the end of the stream,
 * 1 on a stream error, 2 on a read error (both said on stderr with the path). */
#define DSL_FILE_MORE (-1)
static int dsl_file_continue(dsl_player *p, dsl_file *in, int r, const char *path)
{
    if (r == DSL_DONE) return 0;
    if (r == DSL_ERROR) {
        fflush(stdout);
        fprintf(stderr, "error: %s: %s\n", path, p->error);
        return 1;
    }
    if (dsl_file_pump(p, in)) {
        fprintf(stderr, "error: %s: read error\n", path);
        return 2;
    }
    return DSL_FILE_MORE;
}

#endif
