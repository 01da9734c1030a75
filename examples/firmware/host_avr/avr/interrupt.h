/* host_avr/avr/interrupt.h - the interrupt handler is a plain function the host calls */
#ifndef HOST_AVR_INTERRUPT_H
#define HOST_AVR_INTERRUPT_H
#define ISR(vector) void vector(void)
#define cli() ((void)0)
#define sei() ((void)0)
#endif
