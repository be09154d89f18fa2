/* hal_stm32.h - STM32-only parts of the HAL used by main.c and the fault handlers. */
#ifndef HAL_STM32_H
#define HAL_STM32_H

#include <stdint.h>

#include "hal.h"
#include "trigger_core.h"

#ifndef EMULATED_TIMER_HZ
/* Input clock of QEMU's stm32f2xx timer model, which ignores RCC (QEMU 7.2 default 1 GHz;
 * checked against host time through PING/PONG: see README). */
#define EMULATED_TIMER_HZ 1000000000u
#endif

typedef struct {
    uint32_t sysclk_hz, pclk1_hz, tim_apb1_hz;
    int pll_locked; /* HSE + PLL 168 MHz running */
    int emulated;   /* RCC not modelled (QEMU): clock setup, UID and watchdog skipped */
} hal_clocks_t;

/* Bring up clocks, GPIO, timers, USART2, SysTick and the watchdog; returns the HELLO capabilities bits. */
uint32_t hal_init(trig_core_t *c);
const hal_clocks_t *hal_clocks(void);
int hal_uart_read(uint8_t *out);
void hal_uart_kick(void);
void hal_watchdog_kick(void);
void hal_outputs_inactive(void);
/* Emulation only (no-op on silicon): synthesise the pulse-start event from the device clock. */
void hal_emulated_poll(void);

#endif /* HAL_STM32_H */
