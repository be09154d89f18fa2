/*
 * hal.h - the seam between the portable trigger core (trigger_core.c) and the hardware.
 * src/hal_stm32.c implements it on the STM32F407 (and under QEMU netduinoplus2); test/test_core.c implements a
 * scripted fake for host unit tests.
 */
#ifndef HAL_H
#define HAL_H

#include <stddef.h>
#include <stdint.h>

#include "trigger_types.h"

/* 64-bit device clock, microseconds since boot (a 32-bit 1 MHz timer extended in software). */
uint64_t hal_time_us(void);
/* Milliseconds since boot (SysTick). */
uint32_t hal_millis(void);
/* Queue `len` bytes for transmission without blocking: all of them (returns len) or none (returns 0). */
size_t hal_uart_write(const uint8_t *data, size_t len);
/* Start generating pulses from `table` (the first pulse starts about 1 us later, width table->exposure_us[0]).
 * The hardware calls trig_core_on_pulse() at the start of every pulse. */
void hal_trigger_start(const trig_table_t *table);
/* Stop the pulse timer and force both outputs to the inactive level. Idempotent. */
void hal_trigger_stop(void);
/* 96-bit unique device id. */
void hal_uid(uint8_t out[12]);
/* Mask interrupts; returns the previous mask state for hal_irq_restore(). */
uint32_t hal_irq_save(void);
void hal_irq_restore(uint32_t state);
/* Status LED (on while running). */
void hal_led(int on);

#endif /* HAL_H */
