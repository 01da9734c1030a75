/*
 * delta_servo_player.ino - replay a deltaslice stream on an Arduino (Uno or Mega).
 *
 * Three hobby servos (delta_etitc: the counts ARE pulse widths in microseconds,
 * zero_count 1250 us, 11.111 us per degree) and an extruder stepper (step/dir; the
 * tool channel counts microsteps). A 1 kHz Timer2 interrupt pops one sample per
 * period from a small ring and writes it out; loop() feeds the stream from the
 * serial port (or an SD card) into the player and refills the ring. The player
 * releases a block's samples only after its CRC-32 has been checked.
 *
 * Memory (Uno, 2 KiB RAM): player with two 512-byte record buffers (receive the
 * next block while the current one plays) and a 40-byte message ~1.2 KiB, ring 8 samples x 4 channels
 * 128 bytes, Serial 2 x 64 bytes, Servo ~50 bytes. Tight but fits; on a Mega or an
 * ESP32 raise RING and use SD freely.
 *
 * Serial protocol (115200 baud): the host sends the file in 64-byte chunks, each
 * only after the board has sent one '>' credit (the Uno's serial receive buffer is
 * 64 bytes). The board prints "OK <samples>" at the end or "ERR <message>".
 * At ~1 byte per sample the link (11.5 kB/s) carries 10x the 1 kHz need.
 */
#define DSL_BUFFERS 2
#define DSL_ERROR_LEN 40
#include "dsl_player.h"   /* copy examples/firmware/dsl_player.h next to this sketch */
#include <Servo.h>

/* #define SOURCE_SD 1 */  /* read /PART.DSL from an SD card (SPI, CS pin 10) instead of serial */
#ifdef SOURCE_SD
#include <SD.h>
File source;
#endif

#define EXPECTED_FINGERPRINT 0x6b02f22bUL /* delta_etitc: `deltaslice decode part.dsl --units | head -3` */
#define RING 8                            /* samples buffered between loop() and the ISR (power of 2) */
#define N_CH 4

static const uint8_t SERVO_PIN[3] = {9, 10, 11};
static const uint8_t E_STEP_PIN = 2, E_DIR_PIN = 3;

static dsl_player player;
static Servo servo[3];
static volatile int32_t ring[RING][N_CH];
static volatile uint8_t ring_head, ring_tail; /* ISR reads head, loop() writes tail */
static volatile uint8_t running;
static volatile uint16_t underruns;
static volatile int32_t e_pos;                /* extruder microsteps issued so far */
static uint32_t played;

/* 1 kHz: Timer2, CTC, prescaler 64: 16 MHz / 64 / 250 = 1000 Hz (Timer1 belongs to Servo). */
static void start_timer_1khz(void)
{
    noInterrupts();
    TCCR2A = _BV(WGM21);
    TCCR2B = _BV(CS22); /* clk/64 on Timer2 */
    OCR2A = 249;
    TIMSK2 = _BV(OCIE2A);
    interrupts();
}

ISR(TIMER2_COMPA_vect)
{
    if (!running) return;
    if (ring_head == ring_tail) { /* underrun: hold position, count it */
        underruns++;
        return;
    }
    volatile int32_t *s = ring[ring_head];
    for (uint8_t j = 0; j < 3; j++) servo[j].writeMicroseconds((int)s[j]); /* counts are microseconds */
    int32_t target = s[3];
    if (target != e_pos) { /* at 1 kHz a few microsteps at most: pulse them out now */
        digitalWrite(E_DIR_PIN, target > e_pos ? HIGH : LOW);
        while (e_pos != target) {
            digitalWrite(E_STEP_PIN, HIGH);
            delayMicroseconds(2);
            digitalWrite(E_STEP_PIN, LOW);
            e_pos += target > e_pos ? 1 : -1;
        }
    }
    ring_head = (ring_head + 1) & (RING - 1);
}

static void fail(const char *msg)
{
    running = 0;
    Serial.print(F("ERR "));
    Serial.println(msg);
    for (;;) {
    } /* servos hold their last pulse; power down the heaters here */
}

void setup()
{
    Serial.begin(115200);
    pinMode(E_STEP_PIN, OUTPUT);
    pinMode(E_DIR_PIN, OUTPUT);
    dsl_init(&player);
#ifdef SOURCE_SD
    if (!SD.begin(10) || !(source = SD.open("PART.DSL"))) fail("no SD card or PART.DSL");
#endif
    start_timer_1khz();
}

/* Offer the player bytes from the source; returns 0 at end of input. */
static uint8_t pump_input(void)
{
    static uint8_t chunk[16];
    static uint8_t n, off;
    static uint8_t credit_sent;
    if (off == n) {
#ifdef SOURCE_SD
        n = (uint8_t)source.read(chunk, sizeof chunk);
        off = 0;
        if (n == 0) return 0;
#else
        static uint8_t received; /* bytes of the current 64-byte credit */
        if (!credit_sent) {
            Serial.write('>');
            credit_sent = 1;
            received = 0;
        }
        n = 0;
        off = 0;
        while (n < sizeof chunk && Serial.available()) chunk[n++] = (uint8_t)Serial.read();
        received += n;
        if (received >= 64) credit_sent = 0;
        /* end of input on serial: the end record arrives and dsl_next returns DSL_DONE */
#endif
    }
    off += (uint8_t)dsl_feed(&player, chunk + off, n - off);
    return 1;
}

void loop()
{
    int32_t counts[DSL_MAX_CHANNELS];
    if (!pump_input()) dsl_finish(&player); /* SD file ended */
    if (player.header_ok && !running && played == 0) {
        if (player.fingerprint != EXPECTED_FINGERPRINT) fail("stream compiled for another printer");
        if (player.rate_mhz != 1000000UL || player.n_channels != N_CH) fail("stream is not 1 kHz, 4 channels");
        for (uint8_t j = 0; j < 3; j++) servo[j].attach(SERVO_PIN[j]);
    }
    /* refill the ring while there is room */
    while (((ring_tail + 1) & (RING - 1)) != ring_head) {
        int r = dsl_next(&player, counts);
        if (r == DSL_SAMPLE) {
            for (uint8_t c = 0; c < N_CH; c++) ring[ring_tail][c] = counts[c];
            ring_tail = (ring_tail + 1) & (RING - 1);
            if (played++ == 0) e_pos = counts[3]; /* the extruder starts where the stream starts */
            if (played >= RING - 1) running = 1;
        } else if (r == DSL_DONE) {
            while (ring_head != ring_tail) {
            } /* let the ISR play the last samples */
            running = 0;
            Serial.print(F("OK "));
            Serial.println(played);
            for (;;) {
            }
        } else if (r == DSL_ERROR) {
            fail(player.error); /* every sample released so far came from an intact block */
        } else {
            break; /* DSL_AGAIN: need more bytes */
        }
    }
}
