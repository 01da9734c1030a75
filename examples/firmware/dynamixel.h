/*
 * dynamixel.h - Dynamixel protocol 1.0 instruction packets (AX-12/AX-18 series), portable C99.
 *
 * Layout (ROBOTIS e-Manual, "Protocol 1.0", instruction packet):
 *     0xFF 0xFF ID LENGTH INSTRUCTION PARAM_1 ... PARAM_N CHECKSUM
 *     LENGTH   = N + 2 (the parameters, the instruction and the checksum)
 *     CHECKSUM = ~(ID + LENGTH + INSTRUCTION + PARAM_1 + ... + PARAM_N), lowest byte
 * SYNC_WRITE (0x83) goes to the broadcast ID 0xFE, no status packet comes back; its parameters
 * are the start address, the data length L per servo, then per servo its ID and L data bytes:
 *     LENGTH = (L + 1) * servos + 4
 * AX control table: 24 torque enable (1 byte), 30 goal position (2 bytes, little-endian,
 * 0..1023 for 0..300 deg), 32 moving speed (2 bytes).
 */
#ifndef DYNAMIXEL_H
#define DYNAMIXEL_H

#include <stddef.h>
#include <stdint.h>

#define DXL_BROADCAST 0xFE
#define DXL_WRITE_DATA 0x03
#define DXL_SYNC_WRITE 0x83
#define DXL_TORQUE_ENABLE 24
#define DXL_GOAL_POSITION 30
#define DXL_POSITION_MAX 1023
#define DXL_MAX_SERVOS 8
#define DXL_MAX_PACKET (8 + DXL_MAX_SERVOS * 3)

static uint8_t dxl_checksum(const uint8_t *packet, size_t len)
{
    uint8_t sum = 0;
    size_t k;
    for (k = 2; k + 1 < len; k++) sum = (uint8_t)(sum + packet[k]); /* ID .. last parameter */
    return (uint8_t)~sum;
}

/* WRITE_DATA of n bytes at address to one servo; returns the packet length. */
static size_t dxl_write(uint8_t *out, uint8_t id, uint8_t address, const uint8_t *data, uint8_t n)
{
    size_t len = 7u + n, k;
    out[0] = 0xFF;
    out[1] = 0xFF;
    out[2] = id;
    out[3] = (uint8_t)(n + 3);
    out[4] = DXL_WRITE_DATA;
    out[5] = address;
    for (k = 0; k < n; k++) out[6 + k] = data[k];
    out[len - 1] = dxl_checksum(out, len);
    return len;
}

/* SYNC_WRITE of one 2-byte value per servo (goal positions) at address; values clamped to
   0..DXL_POSITION_MAX. Returns the packet length. */
static size_t dxl_sync_write_u16(uint8_t *out, uint8_t address, const uint8_t *ids, const int32_t *values, uint8_t n)
{
    size_t len = 8u + 3u * n, k;
    out[0] = 0xFF;
    out[1] = 0xFF;
    out[2] = DXL_BROADCAST;
    out[3] = (uint8_t)(3 * n + 4);
    out[4] = DXL_SYNC_WRITE;
    out[5] = address;
    out[6] = 2;
    for (k = 0; k < n; k++) {
        int32_t v = values[k] < 0 ? 0 : values[k] > DXL_POSITION_MAX ? DXL_POSITION_MAX : values[k];
        out[7 + 3 * k] = ids[k];
        out[8 + 3 * k] = (uint8_t)(v & 0xFF);
        out[9 + 3 * k] = (uint8_t)(v >> 8);
    }
    out[len - 1] = dxl_checksum(out, len);
    return len;
}

/* Microseconds a packet of len bytes takes on the bus (8N1: 10 bits a byte). */
static uint32_t dxl_packet_us(size_t len, uint32_t baud)
{
    return (uint32_t)((10ull * len * 1000000ull + baud - 1) / baud);
}

#endif
