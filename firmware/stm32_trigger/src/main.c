/*
 * main.c - STM32F407 trigger firmware: bring up the hardware, announce with HELLO, then loop:
 * feed received bytes to the protocol core, send queued events and heartbeats, kick the watchdog.
 */
#include "hal_stm32.h"
#include "trigger_core.h"

static trig_core_t core;

int main(void)
{
    trig_core_init(&core, 0u);
    uint32_t caps = hal_init(&core);
    core.capabilities = caps;
    trig_core_boot(&core, hal_millis());
    for (;;) {
        uint8_t b;
        while (hal_uart_read(&b)) {
            trig_core_rx_byte(&core, b);
        }
        trig_core_poll(&core, hal_millis());
        (void)hal_time_us(); /* keeps the 64-bit extension of the 32-bit device clock current */
        hal_emulated_poll();
        hal_uart_kick();
        hal_watchdog_kick();
    }
}
