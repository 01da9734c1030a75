/*
 * dsl_player.h - reference player of the deltaslice binary setpoint stream (.dsl, versions 1 and 2).
 *
 * Portable C99, header only, no malloc, no floating point, fixed buffers.
 * Specification: docs/stream-format.md. Feed the stream byte by byte or in chunks
 * from any source (serial, SD card, file); take samples out one at a time. A block's
 * samples are released only after its CRC-32 and structure have been checked.
 *
 *     dsl_player p;
 *     dsl_init(&p);
 *     for (;;) {
 *         int32_t counts[DSL_MAX_CHANNELS];
 *         int r;
 *         while ((r = dsl_next(&p, counts)) == DSL_SAMPLE || r == DSL_EVENT) {
 *             if (r == DSL_EVENT) act(p.event_kind, p.event_value);  // before the next sample
 *             else use(counts);                                      // p.n_channels values
 *         }
 *         if (r == DSL_DONE) break;                  // end record checked: stream complete
 *         if (r == DSL_ERROR) { report(p.error); break; }
 *         // r == DSL_AGAIN: give it more bytes (dsl_feed consumes fewer than offered
 *         // when its record buffers are full: take samples, then offer the rest again)
 *         if (have_bytes) used = dsl_feed(&p, data, len); else dsl_finish(&p);  // finish = end of input
 *     }
 *
 * Memory: DSL_BUFFERS record buffers of DSL_MAX_RECORD (512) bytes each, plus about
 * 150 bytes of state and a DSL_ERROR_LEN-byte message (sizeof(dsl_player) on a PC:
 * 864 bytes with one buffer, 1376 with two, with DSL_MAX_EVENTS 4). DSL_BUFFERS = 1 (default) suits a player that may stop reading
 * while it plays a block (file, SD card); 2 lets it receive the next block while the
 * current one plays (serial link). Event records (version 2: heaters, fan, laser mode) wait in
 * a queue of DSL_MAX_EVENTS (default 4, 12 bytes each) until the samples before them are played;
 * the receive side stops consuming bytes while that queue is full.
 *
 * Define DSL_BUFFERS before including to change it. In exactly the way the Python
 * decoder does, errors are reported only after every sample of the intact blocks
 * before the bad one has been taken out.
 */
#ifndef DSL_PLAYER_H
#define DSL_PLAYER_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#ifndef DSL_BUFFERS
#define DSL_BUFFERS 1
#endif
#ifndef DSL_ERROR_LEN
#define DSL_ERROR_LEN 112 /* error message buffer; 40 is enough for "block N at byte offset M" on small MCUs */
#endif
#if defined(__GNUC__)
#define DSL_MAYBE_UNUSED __attribute__((unused))
#else
#define DSL_MAYBE_UNUSED
#endif
#define DSL_MAX_RECORD 512
#define DSL_MAX_CHANNELS 8
#ifndef DSL_MAX_EVENTS
#define DSL_MAX_EVENTS 4
#endif
#define DSL_VERSION 2 /* the newest version this player knows; it plays 1 too */
#define DSL_EVENT_LEN 16

enum { DSL_ERROR = -1, DSL_AGAIN = 0, DSL_SAMPLE = 1, DSL_DONE = 2, DSL_EVENT = 3 };
/* Event kinds; values are tenths of a degree C for temperatures, 0..255 for the fan, 0/3/4 for
   the laser mode (off, constant M3, dynamic M4). A wait event holds the time base: play the
   next sample only once the heater is at its set temperature. */
enum { DSL_EV_HOTEND_SET = 1, DSL_EV_HOTEND_WAIT = 2, DSL_EV_BED_SET = 3, DSL_EV_BED_WAIT = 4,
       DSL_EV_FAN = 5, DSL_EV_LASER_MODE = 6 };
enum { DSL_KIND_REVOLUTE = 1, DSL_KIND_PRISMATIC = 2, DSL_KIND_EXTRUDER = 3, DSL_KIND_LASER = 4 };

enum { DSL_S_HEADER, DSL_S_RECORD_START, DSL_S_BLOCK, DSL_S_EVENT_RECORD, DSL_S_END_RECORD, DSL_S_END, DSL_S_ERROR };

typedef struct {
    /* --- from the header (valid once header_ok is 1) --- */
    uint8_t header_ok;
    uint8_t version;
    uint8_t n_channels;
    uint8_t kinds[DSL_MAX_CHANNELS];
    uint32_t fingerprint;
    uint32_t rate_mhz;      /* sample period in us = 1e9 / rate_mhz */
    uint16_t max_record;
    /* --- receive side --- */
    uint8_t rx_state;
    uint16_t header_len;
    uint32_t pos;           /* bytes received of the current header or record */
    uint32_t crc;           /* running CRC-32 (pre-inverted) of the current header or record */
    uint32_t stream_crc;    /* running CRC-32 (pre-inverted) of every byte before the end record */
    uint32_t offset;        /* bytes consumed from the stream */
    uint32_t record_offset; /* stream offset of the current record */
    uint32_t rx_blocks;     /* blocks received intact */
    uint32_t rx_samples;    /* samples in those blocks */
    uint8_t small[24];      /* fixed header part, end record */
    uint16_t rec_len;
    uint8_t buf[DSL_BUFFERS][DSL_MAX_RECORD];
    uint8_t q_head, q_count; /* checked blocks waiting or playing, buf[q_head] first */
    struct { uint32_t index; int32_t value; uint8_t kind; } ev[DSL_MAX_EVENTS]; /* checked events, in order */
    uint8_t ev_head, ev_count;
    /* --- play side --- */
    uint8_t playing;
    uint16_t n, i;          /* samples in the playing block, next sample */
    uint32_t bitpos;        /* bit cursor in buf[q_head] */
    uint8_t order[DSL_MAX_CHANNELS], width[DSL_MAX_CHANNELS];
    int32_t x[DSL_MAX_CHANNELS], v[DSL_MAX_CHANNELS];
    uint32_t sample_index;  /* index of the next sample released */
    uint32_t event_index;   /* the event dsl_next last returned: before sample event_index */
    int32_t event_value;
    uint8_t event_kind;
    char error[DSL_ERROR_LEN];
    const char *error_what; /* the error's cause without its place (in flash on AVR), for a player
                               that prints the whole message itself rather than keep it in RAM */
    uint8_t error_in_header;
} dsl_player;

/* ---- CRC-32 (IEEE, reflected 0xEDB88320), 16-entry nibble table: 64 bytes ---- */
#if defined(__AVR__)
#include <avr/pgmspace.h>
#define DSL_STR(s) PSTR(s)
#define DSL_TABLE_ATTR PROGMEM
#define DSL_TABLE_READ(t, i) pgm_read_dword(&(t)[i])
#else
#define DSL_STR(s) (s)
#define DSL_TABLE_ATTR
#define DSL_TABLE_READ(t, i) ((t)[i])
#endif

static const uint32_t dsl_crc_nibble[16] DSL_TABLE_ATTR = {
    0x00000000UL, 0x1DB71064UL, 0x3B6E20C8UL, 0x26D930ACUL, 0x76DC4190UL, 0x6B6B51F4UL, 0x4DB26158UL, 0x5005713CUL,
    0xEDB88320UL, 0xF00F9344UL, 0xD6D6A3E8UL, 0xCB61B38CUL, 0x9B64C2B0UL, 0x86D3D2D4UL, 0xA00AE278UL, 0xBDBDF21CUL};

static uint32_t dsl_crc_byte(uint32_t crc, uint8_t b)
{
    crc ^= b;
    crc = (crc >> 4) ^ DSL_TABLE_READ(dsl_crc_nibble, crc & 15u);
    crc = (crc >> 4) ^ DSL_TABLE_READ(dsl_crc_nibble, crc & 15u);
    return crc;
}

static uint32_t dsl_crc_final(uint32_t crc) { return (uint32_t)(crc ^ (uint32_t)0xFFFFFFFFUL); }

static uint16_t dsl_u16(const uint8_t *b) { return (uint16_t)(b[0] | ((uint16_t)b[1] << 8)); }
static uint32_t dsl_u32(const uint8_t *b)
{
    return (uint32_t)b[0] | ((uint32_t)b[1] << 8) | ((uint32_t)b[2] << 16) | ((uint32_t)b[3] << 24);
}

static const uint8_t dsl_magic[8] = {0x89, 'D', 'S', 'L', '\r', '\n', 0x1A, '\n'};

static void dsl_init(dsl_player *p)
{
    size_t k;
    unsigned char *z = (unsigned char *)p;
    for (k = 0; k < sizeof *p; k++) z[k] = 0;
    p->rx_state = DSL_S_HEADER;
    p->crc = 0xFFFFFFFFUL;
    p->stream_crc = 0xFFFFFFFFUL;
}

/* what: a message in flash on AVR (DSL_STR), so the player's strings take no RAM there. */
static void dsl_fail(dsl_player *p, const char *what)
{
    p->error_what = what;
    p->error_in_header = p->rx_state == DSL_S_HEADER;
#if defined(__AVR__)
    if (p->rx_state == DSL_S_HEADER)
        snprintf_P(p->error, sizeof p->error, PSTR("header: %S"), what);
    else
        snprintf_P(p->error, sizeof p->error, PSTR("block %lu at byte offset %lu: %S"), (unsigned long)p->rx_blocks,
                   (unsigned long)p->record_offset, what);
#else
    if (p->rx_state == DSL_S_HEADER)
        snprintf(p->error, sizeof p->error, "header: %s", what);
    else
        snprintf(p->error, sizeof p->error, "block %lu at byte offset %lu: %s", (unsigned long)p->rx_blocks,
                 (unsigned long)p->record_offset, what);
#endif
    p->rx_state = DSL_S_ERROR;
}

/* Read an unsigned LEB128 varint (<= 5 bytes) from b[*pos .. end). 0 on success. */
static int dsl_varint(const uint8_t *b, uint32_t *pos, uint32_t end, uint32_t *out)
{
    uint32_t value = 0;
    unsigned shift = 0;
    for (;;) {
        uint8_t c;
        if (*pos >= end || shift > 28) return -1;
        c = b[(*pos)++];
        value |= (uint32_t)(c & 0x7F) << shift;
        shift += 7;
        if (!(c & 0x80)) break;
    }
    *out = value;
    return 0;
}

static int32_t dsl_unzigzag(uint32_t u) { return (int32_t)((u >> 1) ^ (0u - (u & 1u))); }

/* Parse the channel headers of a record in b; load them into the play state when load != 0.
   Returns 0 when the record's structure matches its length. */
static int dsl_parse_block(dsl_player *p, const uint8_t *b, int load)
{
    uint32_t len = dsl_u16(b + 1), n = dsl_u16(b + 3), end = len - 4, pos = 5, row_bits = 0, need;
    uint8_t c;
    if (n < 1) return -1;
    for (c = 0; c < p->n_channels; c++) {
        uint8_t mode, order, width;
        uint32_t x0, v0 = 0;
        if (pos >= end) return -1;
        mode = b[pos++];
        order = (uint8_t)(mode >> 6);
        width = (uint8_t)(mode & 0x3F);
        if ((order != 1 && order != 2) || width > 32) return -1;
        if (dsl_varint(b, &pos, end, &x0)) return -1;
        if (order == 2 && dsl_varint(b, &pos, end, &v0)) return -1;
        row_bits += width;
        if (load) {
            p->order[c] = order;
            p->width[c] = width;
            p->x[c] = dsl_unzigzag(x0);
            p->v[c] = dsl_unzigzag(v0);
        }
    }
    need = ((n - 1) * row_bits + 7) / 8;
    if (end - pos != need) return -1;
    if (load) {
        p->n = (uint16_t)n;
        p->i = 0;
        p->bitpos = pos * 8;
    }
    return 0;
}

static void dsl_rx_byte(dsl_player *p, uint8_t b)
{
    uint32_t pos = p->pos;
    switch (p->rx_state) {
    case DSL_S_HEADER:
        if (pos < 8 && b != dsl_magic[pos]) {
            dsl_fail(p, DSL_STR("not a deltaslice stream (bad magic at byte offset 0)"));
            return;
        }
        if (pos < 24) p->small[pos] = b;
        if (pos == 23) {
            p->header_len = dsl_u16(p->small + 10);
            p->fingerprint = dsl_u32(p->small + 12);
            p->rate_mhz = dsl_u32(p->small + 16);
            p->n_channels = p->small[20];
            p->max_record = dsl_u16(p->small + 22);
            if (dsl_u16(p->small + 8) < 1 || dsl_u16(p->small + 8) > DSL_VERSION) {
                dsl_fail(p, DSL_STR("stream format version not supported (this player knows 1 and 2)"));
                return;
            }
            p->version = (uint8_t)dsl_u16(p->small + 8);
            if (p->n_channels < 2 || p->n_channels > DSL_MAX_CHANNELS || p->rate_mhz == 0 ||
                p->header_len < 24u + 17u * p->n_channels + 7u) {
                dsl_fail(p, DSL_STR("header holds invalid values"));
                return;
            }
            if (p->max_record > DSL_MAX_RECORD) {
                dsl_fail(p, DSL_STR("stream needs a record buffer larger than DSL_MAX_RECORD"));
                return;
            }
        }
        if (pos >= 24 && pos < 24u + 17u * p->n_channels && (pos - 24) % 17 == 0) {
            if (b < DSL_KIND_REVOLUTE || b > DSL_KIND_LASER) {
                dsl_fail(p, DSL_STR("invalid channel kind"));
                return;
            }
            p->kinds[(pos - 24) / 17] = b;
        }
        if (pos >= 24 && pos + 4 >= p->header_len) {      /* the 4 CRC bytes */
            p->small[pos + 4 - p->header_len] = b;
        } else {
            p->crc = dsl_crc_byte(p->crc, b);
        }
        p->stream_crc = dsl_crc_byte(p->stream_crc, b);
        p->pos = ++pos;
        if (pos >= 24 && pos == p->header_len) {
            if (dsl_crc_final(p->crc) != dsl_u32(p->small)) {
                dsl_fail(p, DSL_STR("header CRC mismatch: the header is corrupt"));
                return;
            }
            p->header_ok = 1;
            p->rx_state = DSL_S_RECORD_START;
        }
        return;
    case DSL_S_RECORD_START:
        p->record_offset = p->offset;
        p->crc = dsl_crc_byte(0xFFFFFFFFUL, b);
        if (b == 'B') {
            uint8_t *rec = p->buf[(p->q_head + p->q_count) % DSL_BUFFERS];
            rec[0] = b;
            p->stream_crc = dsl_crc_byte(p->stream_crc, b);
            p->rx_state = DSL_S_BLOCK;
        } else if (b == 'V') {
            if (p->version < 2) {
                dsl_fail(p, DSL_STR("event record in a version 1 stream"));
                return;
            }
            p->small[0] = b;
            p->stream_crc = dsl_crc_byte(p->stream_crc, b);
            p->rx_state = DSL_S_EVENT_RECORD;
        } else if (b == 'E') {
            p->small[0] = b;
            p->rx_state = DSL_S_END_RECORD;
        } else {
            dsl_fail(p, DSL_STR("unknown record type (corrupt or out of sync)"));
            return;
        }
        p->pos = 1;
        return;
    case DSL_S_BLOCK: {
        uint8_t *rec = p->buf[(p->q_head + p->q_count) % DSL_BUFFERS];
        rec[pos] = b;
        p->stream_crc = dsl_crc_byte(p->stream_crc, b);
        if (pos == 2) {
            p->rec_len = dsl_u16(rec + 1);
            if (p->rec_len < 5u + 2u * p->n_channels + 4u || p->rec_len > p->max_record) {
                dsl_fail(p, DSL_STR("block length out of range (corrupt)"));
                return;
            }
        }
        if (pos < 3 || pos + 4 < p->rec_len) p->crc = dsl_crc_byte(p->crc, b);
        p->pos = ++pos;
        if (pos >= 3 && pos == p->rec_len) {
            if (dsl_crc_final(p->crc) != dsl_u32(rec + pos - 4)) {
                dsl_fail(p, DSL_STR("CRC mismatch: block is corrupt"));
                return;
            }
            if (dsl_parse_block(p, rec, 0)) {
                dsl_fail(p, DSL_STR("inconsistent block structure"));
                return;
            }
            p->rx_blocks++;
            p->rx_samples += dsl_u16(rec + 3);
            p->q_count++;
            p->rx_state = DSL_S_RECORD_START;
        }
        return;
    }
    case DSL_S_EVENT_RECORD:
        p->small[pos] = b;
        p->stream_crc = dsl_crc_byte(p->stream_crc, b);
        if (pos < 12) p->crc = dsl_crc_byte(p->crc, b);
        p->pos = ++pos;
        if (pos == DSL_EVENT_LEN) {
            uint8_t kind = p->small[7], slot;
            if (dsl_crc_final(p->crc) != dsl_u32(p->small + 12) || dsl_u16(p->small + 1) != DSL_EVENT_LEN) {
                dsl_fail(p, DSL_STR("event record corrupt (CRC mismatch or length)"));
                return;
            }
            if (kind < DSL_EV_HOTEND_SET || kind > DSL_EV_LASER_MODE || dsl_u32(p->small + 3) != p->rx_samples) {
                dsl_fail(p, DSL_STR("event kind not 1..6 or index not the next block's"));
                return;
            }
            slot = (uint8_t)((p->ev_head + p->ev_count) % DSL_MAX_EVENTS);
            p->ev[slot].index = dsl_u32(p->small + 3);
            p->ev[slot].kind = kind;
            p->ev[slot].value = (int32_t)dsl_u32(p->small + 8);
            p->ev_count++;
            p->rx_state = DSL_S_RECORD_START;
        }
        return;
    case DSL_S_END_RECORD:
        p->small[pos] = b;
        if (pos < 11) p->crc = dsl_crc_byte(p->crc, b);
        p->pos = ++pos;
        if (pos == 15) {
            if (dsl_crc_final(p->crc) != dsl_u32(p->small + 11) || dsl_u16(p->small + 1) != 15) {
                dsl_fail(p, DSL_STR("end record corrupt (CRC mismatch)"));
            } else if (dsl_u32(p->small + 3) != p->rx_samples) {
                dsl_fail(p, DSL_STR("end record's sample count disagrees with the blocks"));
            } else if (dsl_u32(p->small + 7) != dsl_crc_final(p->stream_crc)) {
                dsl_fail(p, DSL_STR("whole-stream CRC mismatch"));
            } else {
                p->rx_state = DSL_S_END;
            }
        }
        return;
    case DSL_S_END:
        p->record_offset = p->offset;
        dsl_fail(p, DSL_STR("unexpected bytes after the end record"));
        return;
    default:
        return;
    }
}

/* Offer len bytes; returns how many were consumed. Fewer than len when every record
   buffer holds a checked block (take samples with dsl_next, then offer the rest), or
   after an error. */
static size_t dsl_feed(dsl_player *p, const uint8_t *data, size_t len)
{
    size_t k = 0;
    while (k < len) {
        if (p->rx_state == DSL_S_ERROR) break;
        if (p->rx_state == DSL_S_RECORD_START &&
            ((data[k] == 'B' && p->q_count == DSL_BUFFERS) || (data[k] == 'V' && p->ev_count == DSL_MAX_EVENTS)))
            break;
        dsl_rx_byte(p, data[k]);
        k++;
        p->offset++;
    }
    return k;
}

/* The input has ended: anything but a complete stream is a truncation error. */
DSL_MAYBE_UNUSED static void dsl_finish(dsl_player *p)
{
    if (p->rx_state == DSL_S_END || p->rx_state == DSL_S_ERROR) return;
    if (p->rx_state == DSL_S_HEADER) {
        dsl_fail(p, DSL_STR("stream truncated inside the header"));
    } else if (p->rx_state == DSL_S_RECORD_START) {
        p->record_offset = p->offset;
        dsl_fail(p, DSL_STR("stream truncated: ends without an end record"));
    } else if (p->rx_state == DSL_S_BLOCK) {
        dsl_fail(p, DSL_STR("stream truncated inside the block"));
    } else if (p->rx_state == DSL_S_EVENT_RECORD) {
        dsl_fail(p, DSL_STR("stream truncated inside an event record"));
    } else {
        dsl_fail(p, DSL_STR("stream truncated inside the end record"));
    }
}

static uint32_t dsl_bits(dsl_player *p, const uint8_t *b, uint8_t width)
{
    uint32_t u = 0, bp = p->bitpos;
    uint8_t k;
    for (k = 0; k < width; k++, bp++)
        if ((b[bp >> 3] >> (bp & 7)) & 1u) u |= (uint32_t)1 << k;
    p->bitpos = bp;
    return u;
}

/* Take the next sample: DSL_SAMPLE (counts[0 .. n_channels-1] filled), DSL_EVENT (an event that
   takes effect before the next sample: p->event_kind, p->event_value), DSL_AGAIN (feed more
   bytes), DSL_DONE (stream complete and checked) or DSL_ERROR (see p->error). */
static int dsl_next(dsl_player *p, int32_t *counts)
{
    const uint8_t *b;
    uint8_t c;
    if (p->ev_count && p->ev[p->ev_head].index == p->sample_index) {
        p->event_index = p->ev[p->ev_head].index;
        p->event_kind = p->ev[p->ev_head].kind;
        p->event_value = p->ev[p->ev_head].value;
        p->ev_head = (uint8_t)((p->ev_head + 1) % DSL_MAX_EVENTS);
        p->ev_count--;
        return DSL_EVENT;
    }
    if (!p->playing) {
        if (p->q_count == 0) {
            if (p->rx_state == DSL_S_ERROR) return DSL_ERROR;
            if (p->rx_state == DSL_S_END) return DSL_DONE;
            return DSL_AGAIN;
        }
        dsl_parse_block(p, p->buf[p->q_head], 1);
        p->playing = 1;
    }
    b = p->buf[p->q_head];
    if (p->i > 0) {
        for (c = 0; c < p->n_channels; c++) {
            int32_t r = p->width[c] ? dsl_unzigzag(dsl_bits(p, b, p->width[c])) : 0;
            if (p->order[c] == 2) {
                p->v[c] = (int32_t)((uint32_t)p->v[c] + (uint32_t)r);
                r = p->v[c];
            }
            p->x[c] = (int32_t)((uint32_t)p->x[c] + (uint32_t)r);
        }
    }
    for (c = 0; c < p->n_channels; c++) counts[c] = p->x[c];
    p->i++;
    p->sample_index++;
    if (p->i >= p->n) {            /* block played: free its buffer */
        p->playing = 0;
        p->q_head = (uint8_t)((p->q_head + 1) % DSL_BUFFERS);
        p->q_count--;
    }
    return DSL_SAMPLE;
}

#endif /* DSL_PLAYER_H */
