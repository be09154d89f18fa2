/*
 * hal_stm32.c - hal.h on the STM32F407 (also runs under QEMU netduinoplus2, whose RCC, GPIO and DMA read as 0).
 *
 * Clock: HSE 8 MHz -> PLL 168 MHz (AHB 168, APB1 42, APB2 84 MHz; APB1 timers 84 MHz), every ready-flag wait
 * bounded; on a timeout the chip stays on HSI 16 MHz (and says so in the HELLO capabilities).
 * Host link: USART2 921600 8N1, RX interrupt into a ring buffer, TX from a ring buffer (TXE interrupt + main-loop
 * kick, because QEMU never raises TXE interrupts).
 * Trigger: TIM3 at a 1 MHz tick (a k us tick, k = ceil(period_us / 65536), for periods beyond its 16-bit
 * range), ARR = period_us - 1, CH3 (left) and CH4 (right) in PWM mode 1 from the same
 * counter, compare preload on; the next width is written by DMA1 stream 2 (TIM3_UP, DMA burst into CCR3+CCR4) on
 * each update event, or by the update interrupt where DMA does not exist (QEMU). The update interrupt also stamps
 * the pulse start on the device clock: TIM5, a free-running 32-bit 1 MHz counter extended to 64 bits.
 */
#include "hal_stm32.h"

#include "pins.h"
#include "regs.h"
#include "trigger_core.h"

#ifndef TRIG_ACTIVE_LOW
#define TRIG_ACTIVE_LOW 1 /* upstream cameras: TriggerActivation=FallingEdge, exposure while low */
#endif

#define HSE_HZ 8000000u
#define HSI_HZ 16000000u
#define PLL_SYSCLK_HZ 168000000u
#define READY_TIMEOUT_SPINS 200000u
#define USART_BAUD 921600u
#define RX_RING_LEN 512u /* powers of two */
#define TX_RING_LEN 2048u
/* QEMU's SysTick runs as if the core clock were 168 MHz whatever RCC says (RCC is not modelled; README.md). */
#define EMULATED_CORE_HZ 168000000u

static hal_clocks_t clocks;
static uint32_t caps;
static trig_core_t *core;

static volatile uint32_t ms_ticks;
static trig_timeext_t timeext;

static volatile uint8_t rx_ring[RX_RING_LEN];
static volatile uint32_t rx_head, rx_tail;
static volatile uint32_t rx_overflows;
static volatile uint8_t tx_ring[TX_RING_LEN];
static volatile uint32_t tx_head, tx_tail;

static int dma_available;
static uint32_t dma_buf[2u * TRIG_MAX_BRACKETS]; /* (CCR3, CCR4) pairs, burst-written on each update */
static volatile uint32_t trig_arr;
static volatile uint32_t trig_tick_us = 1u; /* TIM3 tick: 1 us, or k us for periods > 65.536 ms (16-bit ARR) */
static uint64_t emu_next_pulse_us; /* emulation only: start of the next synthesised pulse */
static uint32_t emu_period_us;     /* emulation only: 0 while stopped */

/* ------------------------------------------------------------------ helpers */

uint32_t hal_irq_save(void)
{
    uint32_t primask;
    __asm volatile("mrs %0, primask\n cpsid i" : "=r"(primask)::"memory");
    return primask;
}

void hal_irq_restore(uint32_t state)
{
    __asm volatile("msr primask, %0" ::"r"(state) : "memory");
}

static void nvic_enable(uint32_t irq, uint8_t priority)
{
    NVIC_IPR8(irq) = (uint8_t)(priority << 4);
    NVIC_ISER(irq / 32u) = 1u << (irq % 32u);
}

static int wait_mask(volatile uint32_t *reg, uint32_t mask, uint32_t want)
{
    for (uint32_t i = 0; i < READY_TIMEOUT_SPINS; i++) {
        if ((*reg & mask) == want) {
            return 1;
        }
    }
    return 0;
}

static void gpio_mode(unsigned pin, uint32_t mode)
{
    unsigned port = PIN_PORT(pin), num = PIN_NUM(pin);
    GPIO_MODER(port) = (GPIO_MODER(port) & ~(3u << (2u * num))) | (mode << (2u * num));
}

static void gpio_af(unsigned pin, uint32_t af)
{
    unsigned port = PIN_PORT(pin), num = PIN_NUM(pin);
    volatile uint32_t *afr = &GPIO_AFR(port, num / 8u);
    *afr = (*afr & ~(0xFu << (4u * (num % 8u)))) | (af << (4u * (num % 8u)));
    GPIO_OSPEEDR(port) |= 3u << (2u * num); /* very high speed: sharp trigger edges */
    gpio_mode(pin, GPIO_MODE_AF);
}

static void gpio_write(unsigned pin, int high)
{
    unsigned port = PIN_PORT(pin), num = PIN_NUM(pin);
    GPIO_BSRR(port) = high ? (1u << num) : (1u << (num + 16u));
}

/* Both trigger pins as plain outputs at the inactive level (timer detached). Safe from any context. */
void hal_outputs_inactive(void)
{
    TIM_CR1(TIM3_BASE) &= ~TIM_CR1_CEN;
    gpio_write(PIN_TRIG_LEFT, TRIG_ACTIVE_LOW);
    gpio_write(PIN_TRIG_RIGHT, TRIG_ACTIVE_LOW);
    gpio_mode(PIN_TRIG_LEFT, GPIO_MODE_OUTPUT);
    gpio_mode(PIN_TRIG_RIGHT, GPIO_MODE_OUTPUT);
}

/* ------------------------------------------------------------------ clock */

static void clock_init(void)
{
    clocks.emulated = (RCC_CR & RCC_CR_HSIRDY) == 0u; /* HSI is always ready after reset on silicon */
    clocks.sysclk_hz = HSI_HZ;
    clocks.pclk1_hz = HSI_HZ;
    clocks.tim_apb1_hz = HSI_HZ;
    clocks.pll_locked = 0;
    if (clocks.emulated) {
        clocks.sysclk_hz = EMULATED_CORE_HZ;
        return;
    }
    RCC_CR |= RCC_CR_HSEON;
    if (!wait_mask(&RCC_CR, RCC_CR_HSERDY, RCC_CR_HSERDY)) {
        RCC_CR &= ~RCC_CR_HSEON;
        return;
    }
    FLASH_ACR = FLASH_ACR_LATENCY_5WS | FLASH_ACR_PRFTEN | FLASH_ACR_ICEN | FLASH_ACR_DCEN;
    RCC_CFGR = (RCC_CFGR & ~((7u << 10) | (7u << 13) | (0xFu << 4))) | RCC_CFGR_PPRE1_DIV4 | RCC_CFGR_PPRE2_DIV2;
    /* PLL: VCO = HSE / M * N = 8 / 8 * 336 = 336 MHz; SYSCLK = VCO / P(2) = 168 MHz; USB = VCO / Q(7) = 48 MHz */
    RCC_PLLCFGR = 8u | (336u << 6) | (0u << 16) | RCC_PLLCFGR_SRC_HSE | (7u << 24);
    RCC_CR |= RCC_CR_PLLON;
    if (!wait_mask(&RCC_CR, RCC_CR_PLLRDY, RCC_CR_PLLRDY)) {
        RCC_CR &= ~RCC_CR_PLLON;
        RCC_CFGR &= ~((7u << 10) | (7u << 13));
        return;
    }
    RCC_CFGR = (RCC_CFGR & ~RCC_CFGR_SW_MASK) | RCC_CFGR_SW_PLL;
    if (!wait_mask(&RCC_CFGR, RCC_CFGR_SWS_MASK, RCC_CFGR_SWS_PLL)) {
        RCC_CFGR = (RCC_CFGR & ~(RCC_CFGR_SW_MASK | (7u << 10) | (7u << 13))) | RCC_CFGR_SW_HSI;
        return;
    }
    clocks.sysclk_hz = PLL_SYSCLK_HZ;
    clocks.pclk1_hz = PLL_SYSCLK_HZ / 4u;
    clocks.tim_apb1_hz = 2u * clocks.pclk1_hz; /* APB1 prescaler != 1: timers run at twice PCLK1 */
    clocks.pll_locked = 1;
}

/* ------------------------------------------------------------------ time */

void SysTick_Handler(void)
{
    ms_ticks++;
}

uint32_t hal_millis(void)
{
    return ms_ticks;
}

uint64_t hal_time_us(void)
{
    uint32_t s = hal_irq_save();
    uint64_t t = trig_timeext_extend(&timeext, TIM_CNT(TIM5_BASE));
    hal_irq_restore(s);
    return t;
}

static uint32_t tim_prescaler_1mhz(void)
{
    /* QEMU's timer model ignores RCC; it counts at EMULATED_TIMER_HZ before the prescaler. */
    uint32_t hz = clocks.emulated ? EMULATED_TIMER_HZ : clocks.tim_apb1_hz;
    return hz / 1000000u - 1u;
}

/* TIM3 is 16-bit: periods up to 65536 us run on a 1 us tick; longer ones (up to 1 s) on a k us tick, k <= 16,
 * with widths and period rounded to the nearest tick. */
static uint32_t to_ticks(uint32_t us)
{
    uint32_t t = (us + trig_tick_us / 2u) / trig_tick_us;
    return t ? t : 1u;
}

static void devclock_init(void)
{
    TIM_CR1(TIM5_BASE) = 0u;
    TIM_PSC(TIM5_BASE) = tim_prescaler_1mhz();
    TIM_ARR(TIM5_BASE) = 0xFFFFFFFFu;
    TIM_EGR(TIM5_BASE) = TIM_EGR_UG; /* load the prescaler */
    TIM_SR(TIM5_BASE) = 0u;
    TIM_CNT(TIM5_BASE) = 0u;
    trig_timeext_init(&timeext, 0u);
    TIM_CR1(TIM5_BASE) = TIM_CR1_CEN;
}

/* ------------------------------------------------------------------ USART2 */

static void uart_init(void)
{
    gpio_af(PIN_USART2_TX, PIN_USART2_TX_AF);
    gpio_af(PIN_USART2_RX, PIN_USART2_RX_AF);
    GPIO_PUPDR(PIN_PORT(PIN_USART2_RX)) |= 1u << (2u * PIN_NUM(PIN_USART2_RX)); /* pull-up: idle line high */
    USART2_CR1 = 0u;
    USART2_BRR = (clocks.pclk1_hz + USART_BAUD / 2u) / USART_BAUD; /* oversampling 16: mantissa.fraction/16 */
    USART2_CR2 = 0u;
    USART2_CR3 = 0u;
    USART2_CR1 = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE | USART_CR1_RXNEIE;
    nvic_enable(IRQ_USART2, 2u);
}

void USART2_IRQHandler(void)
{
    uint32_t sr = USART2_SR;
    if (sr & (USART_SR_RXNE | USART_SR_ORE)) {
        uint8_t b = (uint8_t)USART2_DR; /* reading DR also clears ORE */
        if (rx_head - rx_tail < RX_RING_LEN) {
            rx_ring[rx_head % RX_RING_LEN] = b;
            rx_head++;
        } else {
            rx_overflows++;
        }
    }
    if ((USART2_CR1 & USART_CR1_TXEIE) && (sr & USART_SR_TXE)) {
        if (tx_tail != tx_head) {
            USART2_DR = tx_ring[tx_tail % TX_RING_LEN];
            tx_tail++;
        } else {
            USART2_CR1 &= ~USART_CR1_TXEIE;
        }
    }
}

int hal_uart_read(uint8_t *out)
{
    if (rx_tail == rx_head) {
        return 0;
    }
    *out = rx_ring[rx_tail % RX_RING_LEN];
    rx_tail++;
    return 1;
}

size_t hal_uart_write(const uint8_t *data, size_t len)
{
    uint32_t s = hal_irq_save();
    if (TX_RING_LEN - (tx_head - tx_tail) < len) {
        hal_irq_restore(s);
        return 0u;
    }
    for (size_t i = 0; i < len; i++) {
        tx_ring[tx_head % TX_RING_LEN] = data[i];
        tx_head++;
    }
    USART2_CR1 |= USART_CR1_TXEIE;
    hal_irq_restore(s);
    return len;
}

void hal_uart_kick(void)
{
    uint32_t s = hal_irq_save();
    while (tx_tail != tx_head && (USART2_SR & USART_SR_TXE)) {
        USART2_DR = tx_ring[tx_tail % TX_RING_LEN];
        tx_tail++;
    }
    hal_irq_restore(s);
}

/* ------------------------------------------------------------------ trigger timer */

static int dma_probe(void)
{
    DMA_S_CR(2) = 0u;
    DMA_S_NDTR(2) = 0x1234u;
    return DMA_S_NDTR(2) == 0x1234u; /* QEMU: unimplemented device, reads 0 */
}

static void trigger_init(void)
{
    hal_outputs_inactive();
    TIM_CR1(TIM3_BASE) = 0u;
    TIM_DIER(TIM3_BASE) = 0u;
    TIM_CCMR2(TIM3_BASE) = (TIM_OCM_FORCE_INACTIVE << TIM_CCMR2_OC3M_SHIFT) |
                           (TIM_OCM_FORCE_INACTIVE << TIM_CCMR2_OC4M_SHIFT);
    dma_available = dma_probe();
    nvic_enable(IRQ_TIM3, 0u); /* highest priority: pulse stamps */
}

void hal_trigger_start(const trig_table_t *t)
{
    uint32_t n = t->n;
    uint32_t s = hal_irq_save();

    TIM_CR1(TIM3_BASE) = 0u;
    TIM_DIER(TIM3_BASE) = 0u;
    DMA_S_CR(2) = 0u;
    trig_tick_us = (t->period_us + 65535u) / 65536u;
    TIM_PSC(TIM3_BASE) = (tim_prescaler_1mhz() + 1u) * trig_tick_us - 1u;
    trig_arr = to_ticks(t->period_us) - 1u;
    TIM_ARR(TIM3_BASE) = trig_arr;
    /* pulse 0 width into the preload registers; UG (with URS: no interrupt, no DMA) loads PSC, ARR and CCRs */
    TIM_CCR3(TIM3_BASE) = to_ticks(t->exposure_us[0]);
    TIM_CCR4(TIM3_BASE) = to_ticks(t->exposure_us[0]);
    TIM_CCMR2(TIM3_BASE) = TIM_CCMR2_OC3PE | TIM_CCMR2_OC4PE | (TIM_OCM_PWM1 << TIM_CCMR2_OC3M_SHIFT) |
                           (TIM_OCM_PWM1 << TIM_CCMR2_OC4M_SHIFT);
    TIM_CCER(TIM3_BASE) = TIM_CCER_CC3E | TIM_CCER_CC4E |
                          (TRIG_ACTIVE_LOW ? (TIM_CCER_CC3P | TIM_CCER_CC4P) : 0u);
    TIM_CR1(TIM3_BASE) = TIM_CR1_URS | TIM_CR1_ARPE;
    TIM_EGR(TIM3_BASE) = TIM_EGR_UG;
    TIM_SR(TIM3_BASE) = 0u;
    /* start one tick before the overflow: CNT = ARR >= CCR keeps the outputs inactive, then the first update
     * starts pulse 0 and the pulse interrupt runs for every pulse including the first. */
    TIM_CNT(TIM3_BASE) = trig_arr;
    if (dma_available) {
        /* DMA writes the width of pulse k+1 at the update that starts pulse k */
        for (uint32_t j = 0; j < n; j++) {
            uint32_t w = to_ticks(t->exposure_us[(j + 1u) % n]);
            dma_buf[2u * j] = w;
            dma_buf[2u * j + 1u] = w;
        }
        TIM_DCR(TIM3_BASE) = TIM_DCR_DBA_CCR3 | (1u << TIM_DCR_DBL_SHIFT); /* 2 transfers: CCR3, CCR4 */
        DMA1_LIFCR = DMA_LIFCR_STREAM2_ALL;
        DMA_S_PAR(2) = TIM_DMAR_ADDR(TIM3_BASE);
        DMA_S_M0AR(2) = (uint32_t)(uintptr_t)dma_buf;
        DMA_S_NDTR(2) = 2u * n;
        DMA_S_FCR(2) = 0u; /* direct mode */
        DMA_S_CR(2) = (5u << DMA_CR_CHSEL_SHIFT) | DMA_CR_PL_HIGH | DMA_CR_MSIZE_32 | DMA_CR_PSIZE_32 | DMA_CR_MINC |
                      DMA_CR_CIRC | DMA_CR_DIR_M2P;
        DMA_S_CR(2) |= DMA_CR_EN;
        TIM_DIER(TIM3_BASE) = TIM_DIER_UIE | TIM_DIER_UDE;
    } else {
        TIM_DIER(TIM3_BASE) = TIM_DIER_UIE;
    }
    gpio_af(PIN_TRIG_LEFT, PIN_TRIG_LEFT_AF);
    gpio_af(PIN_TRIG_RIGHT, PIN_TRIG_RIGHT_AF);
    TIM_CR1(TIM3_BASE) = TIM_CR1_URS | TIM_CR1_ARPE | TIM_CR1_CEN;
    if (clocks.emulated) {
        /* QEMU 7.2's stm32f2xx timer model does not keep re-arming its update alarm (its CNT never wraps at ARR),
         * so under emulation the update event is synthesised from the device clock by hal_emulated_poll(). */
        TIM_DIER(TIM3_BASE) = 0u;
        emu_next_pulse_us = trig_timeext_extend(&timeext, TIM_CNT(TIM5_BASE)) + 1u;
        emu_period_us = t->period_us;
    }
    hal_irq_restore(s);
}

void hal_trigger_stop(void)
{
    uint32_t s = hal_irq_save();
    emu_period_us = 0u;
    hal_outputs_inactive();
    TIM_DIER(TIM3_BASE) = 0u;
    DMA_S_CR(2) = 0u;
    TIM_CCMR2(TIM3_BASE) = (TIM_OCM_FORCE_INACTIVE << TIM_CCMR2_OC3M_SHIFT) |
                           (TIM_OCM_FORCE_INACTIVE << TIM_CCMR2_OC4M_SHIFT);
    TIM_SR(TIM3_BASE) = 0u;
    hal_irq_restore(s);
}

void hal_emulated_poll(void)
{
    if (!clocks.emulated || emu_period_us == 0u) {
        return;
    }
    uint32_t s = hal_irq_save();
    uint64_t now = trig_timeext_extend(&timeext, TIM_CNT(TIM5_BASE));
    if (now >= emu_next_pulse_us) {
        (void)trig_core_on_pulse(core, emu_next_pulse_us);
        emu_next_pulse_us += emu_period_us;
        if (emu_next_pulse_us <= now) { /* fell behind (host paused QEMU): skip, no burst of stale pulses */
            emu_next_pulse_us = now + emu_period_us;
        }
    }
    hal_irq_restore(s);
}

void TIM3_IRQHandler(void)
{
    if (!(TIM_SR(TIM3_BASE) & TIM_SR_UIF)) {
        return;
    }
    TIM_SR(TIM3_BASE) = ~TIM_SR_UIF;
    /* the pulse started when CNT was 0: subtract the ticks elapsed since (interrupt latency), same 1 MHz tick */
    uint32_t since = TIM_CNT(TIM3_BASE);
    uint64_t now = trig_timeext_extend(&timeext, TIM_CNT(TIM5_BASE));
    if (since > trig_arr) {
        since = 0u;
    }
    since *= trig_tick_us;

    uint32_t next_w = trig_core_on_pulse(core, now - since);
    if (!dma_available && next_w != 0u) {
        TIM_CCR3(TIM3_BASE) = to_ticks(next_w);
        TIM_CCR4(TIM3_BASE) = to_ticks(next_w);
    }
}

/* ------------------------------------------------------------------ misc */

void hal_uid(uint8_t out[12])
{
    for (unsigned i = 0; i < 12u; i++) {
        /* QEMU does not map the system memory holding the UID: report zeros there */
        out[i] = clocks.emulated ? 0u : *(volatile const uint8_t *)(uintptr_t)(UID_BASE + i);
    }
}

void hal_led(int on)
{
    gpio_write(PIN_STATUS_LED, on);
}

static void watchdog_init(void)
{
    if (clocks.emulated) {
        return;
    }
    IWDG_KR = 0x5555u; /* unlock PR/RLR */
    IWDG_PR = 3u;      /* LSI ~32 kHz / 32 = 1 kHz */
    IWDG_RLR = 500u;   /* ~0.5 s */
    IWDG_KR = 0xAAAAu;
    IWDG_KR = 0xCCCCu; /* start: cannot be stopped until reset */
    caps |= TRIG_CAP_WATCHDOG;
}

void hal_watchdog_kick(void)
{
    IWDG_KR = 0xAAAAu;
}

const hal_clocks_t *hal_clocks(void)
{
    return &clocks;
}

uint32_t hal_init(trig_core_t *c)
{
    core = c;
    caps = 0u;
    /* trigger lines to the inactive level first, before the (bounded but slow) clock bring-up */
    RCC_AHB1ENR |= RCC_AHB1ENR_GPIOAEN | RCC_AHB1ENR_GPIOBEN | RCC_AHB1ENR_GPIODEN;
    (void)RCC_AHB1ENR;
    hal_outputs_inactive();
    clock_init();
    if (!clocks.emulated && (RCC_CSR & RCC_CSR_IWDGRSTF)) {
        caps |= TRIG_CAP_IWDG_RESET;
    }
    if (!clocks.emulated) {
        RCC_CSR |= RCC_CSR_RMVF;
    }
    RCC_AHB1ENR |= RCC_AHB1ENR_GPIOAEN | RCC_AHB1ENR_GPIOBEN | RCC_AHB1ENR_GPIODEN | RCC_AHB1ENR_DMA1EN;
    RCC_APB1ENR |= RCC_APB1ENR_TIM3EN | RCC_APB1ENR_TIM5EN | RCC_APB1ENR_USART2EN;
    (void)RCC_APB1ENR; /* read back: the peripheral clock is on before the first access */
    trigger_init();
    gpio_mode(PIN_STATUS_LED, GPIO_MODE_OUTPUT);
    hal_led(0);
    devclock_init();
    SYST_RVR = clocks.sysclk_hz / 1000u - 1u;
    SYST_CVR = 0u;
    SYST_CSR = 7u; /* core clock, interrupt, enable */
    uart_init();
    watchdog_init();
    caps |= dma_available ? TRIG_CAP_DMA_RELOAD : 0u;
    caps |= clocks.pll_locked ? TRIG_CAP_PLL_168MHZ : 0u;
    caps |= clocks.emulated ? TRIG_CAP_EMULATED : 0u;
    caps |= TRIG_ACTIVE_LOW ? TRIG_CAP_ACTIVE_LOW : 0u;
    return caps;
}
