/* host_avr/avr/pgmspace.h - flash strings are plain strings on a PC */
#ifndef HOST_AVR_PGMSPACE_H
#define HOST_AVR_PGMSPACE_H
#define PROGMEM
#define PSTR(s) (s)
#define pgm_read_byte(p) (*(const uint8_t *)(p))
#define pgm_read_word(p) (*(const uint16_t *)(p))
#endif
