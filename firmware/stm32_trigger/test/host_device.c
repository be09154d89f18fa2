/*
 * host_device.c - the portable trigger core (trigger_core.c + bproto.c) as a Linux process: the HAL is a file
 * descriptor for the "UART" (e.g. a pty master) and CLOCK_MONOTONIC for the device clock; pulses are generated in
 * real time by the main loop. Lets host tests drive the real C protocol code with the host client, without QEMU.
 *
 *   host_device FD      (FD: an inherited, open, raw descriptor; the process exits when it reaches EOF/EIO
 *                        and SIGTERM ends it)
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "hal.h"
#include "trigger_core.h"

static int uart_fd = -1;
static uint64_t boot_ns;
static trig_core_t core;
static uint64_t next_pulse_us;
static uint32_t period_us; /* 0 while stopped */
static volatile sig_atomic_t stop_requested;

static uint64_t mono_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000ull + (uint64_t)ts.tv_nsec;
}

uint64_t hal_time_us(void) { return (mono_ns() - boot_ns) / 1000u; }
uint32_t hal_millis(void) { return (uint32_t)((mono_ns() - boot_ns) / 1000000u); }

size_t hal_uart_write(const uint8_t *data, size_t len)
{
    size_t done = 0;
    while (done < len) {
        ssize_t n = write(uart_fd, data + done, len - done);
        if (n < 0) {
            if (errno == EINTR || errno == EAGAIN) {
                continue;
            }
            return done == 0 ? 0u : len; /* nobody listening: drop, like a UART without a cable */
        }
        done += (size_t)n;
    }
    return len;
}

void hal_trigger_start(const trig_table_t *table)
{
    period_us = table->period_us;
    next_pulse_us = hal_time_us() + 1u;
}

void hal_trigger_stop(void) { period_us = 0u; }
void hal_uid(uint8_t out[12]) { memcpy(out, "HOSTDEVICE01", 12); }
uint32_t hal_irq_save(void) { return 0u; }
void hal_irq_restore(uint32_t state) { (void)state; }
void hal_led(int on) { (void)on; }

static void on_term(int sig)
{
    (void)sig;
    stop_requested = 1;
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: %s FD\n", argv[0]);
        return 2;
    }
    uart_fd = atoi(argv[1]);
    signal(SIGTERM, on_term);
    boot_ns = mono_ns();
    trig_core_init(&core, (1u << 4) | (1u << 2)); /* exposure while low, emulated */
    trig_core_boot(&core, hal_millis());
    while (!stop_requested) {
        struct pollfd p = {.fd = uart_fd, .events = POLLIN};
        int timeout_ms = 1;
        if (poll(&p, 1, timeout_ms) > 0) {
            uint8_t buf[256];
            ssize_t n = read(uart_fd, buf, sizeof(buf));
            if (n < 0 && errno != EINTR && errno != EAGAIN && errno != EIO) {
                break;
            }
            for (ssize_t i = 0; i < n; i++) {
                trig_core_rx_byte(&core, buf[i]);
            }
            if (n <= 0) {
                struct timespec pause = {0, 10000000L}; /* pty without a peer yet: 10 ms */
                nanosleep(&pause, NULL);
            }
        }
        uint64_t now = hal_time_us();
        if (period_us != 0u && now >= next_pulse_us) {
            (void)trig_core_on_pulse(&core, next_pulse_us);
            next_pulse_us += period_us;
            if (next_pulse_us <= now) {
                next_pulse_us = now + period_us;
            }
        }
        trig_core_poll(&core, hal_millis());
    }
    return 0;
}
