/* The link USART: 8N1, RX interrupt -> ring buffer, TX polled.
 *
 * Flow control without lost bytes: when the ring is full the ISR leaves the byte in DR and masks
 * the interrupt (RXNEIE and the NVIC line); usart_rx_release() unmasks both once there is room.
 * The NVIC mask is what matters under QEMU 7.2: its USART model does not lower the IRQ line when
 * RXNEIE is cleared, so masking RXNEIE alone re-enters the ISR forever (an interrupt storm that
 * starves the main loop which would make room). QEMU's USART model has a 1-byte RX
 * register and does not accept a new byte while RXNE is set, so this gives lossless back-pressure
 * into the host's pty. On silicon a paused receiver overruns (counted); the host's windowed
 * streaming keeps the ring from filling there. */
#include "board.h"
#include "stm32f405_regs.h"

#if UWB_USART == 1
#define LINK_BASE USART1_BASE
#define LINK_IRQn USART1_IRQn
#elif UWB_USART == 3
#define LINK_BASE USART3_BASE
#define LINK_IRQn USART3_IRQn
#else
#error "UWB_USART must be 1 (PA9/PA10) or 3 (PC10/PC11)"
#endif

#define RX_RING_SIZE 1024u /* power of two */


static uint8_t rx_ring[RX_RING_SIZE];
static volatile uint32_t rx_head; /* written by the ISR only */
static volatile uint32_t rx_tail; /* written by the main loop only */
static volatile uint32_t rx_overruns;

/* Pin set-up for silicon (GPIO is not modelled by QEMU; the writes are harmless there). */
static void gpio_af7(uint32_t base, unsigned tx_pin, unsigned rx_pin)
{
    unsigned pins[2];
    unsigned i;
    pins[0] = tx_pin;
    pins[1] = rx_pin;
    for (i = 0; i < 2u; i++) {
        unsigned p = pins[i];
        GPIO_MODER(base) = (GPIO_MODER(base) & ~(3u << (2u * p))) | (2u << (2u * p)); /* AF */
        GPIO_OSPEEDR(base) |= 2u << (2u * p);                                           /* fast */
        if (p < 8u) {
            GPIO_AFRL(base) = (GPIO_AFRL(base) & ~(0xFu << (4u * p))) | (7u << (4u * p));
        } else {
            GPIO_AFRH(base) = (GPIO_AFRH(base) & ~(0xFu << (4u * (p - 8u)))) | (7u << (4u * (p - 8u)));
        }
    }
    GPIO_PUPDR(base) = (GPIO_PUPDR(base) & ~(3u << (2u * rx_pin))) | (1u << (2u * rx_pin)); /* RX pull-up */
}

void usart_init(const board_clocks_t *clk, uint32_t baud)
{
    uint32_t pclk;
#if UWB_USART == 1
    RCC_AHB1ENR |= RCC_AHB1ENR_GPIOA;
    RCC_APB2ENR |= RCC_APB2ENR_USART1;
    gpio_af7(GPIOA_BASE, 9u, 10u);
    pclk = clk->pclk2_hz;
#else
    RCC_AHB1ENR |= RCC_AHB1ENR_GPIOC;
    RCC_APB1ENR |= RCC_APB1ENR_USART3;
    gpio_af7(GPIOC_BASE, 10u, 11u);
    pclk = clk->pclk1_hz;
#endif
    rx_head = 0u;
    rx_tail = 0u;
    rx_overruns = 0u;
    USART_CR1(LINK_BASE) = 0u;
    USART_CR2(LINK_BASE) = 0u; /* 1 stop bit */
    USART_CR3(LINK_BASE) = 0u; /* no hardware flow control */
    USART_BRR(LINK_BASE) = (pclk + baud / 2u) / baud; /* oversampling by 16: BRR = fck / baud */
    USART_CR1(LINK_BASE) = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE | USART_CR1_RXNEIE;
    NVIC_IPR_BYTE(LINK_IRQn) = 0x80u;
    NVIC_ISER(LINK_IRQn / 32u) = 1u << (LINK_IRQn % 32u);
}

/* The body of the link's RX interrupt; the vector (USARTn_IRQHandler in link_irq.S) wraps it to
 * account its own cost, so that stage costs measured by the main loop exclude interrupt time. */
void link_rx_isr(void)
{
    uint32_t sr = USART_SR(LINK_BASE);
    if ((sr & USART_SR_ORE) != 0u) {
        rx_overruns++; /* cleared by the SR read above followed by the DR read below */
    }
    if ((sr & (USART_SR_RXNE | USART_SR_ORE)) != 0u) {
        uint32_t head = rx_head;
        if (head - rx_tail >= RX_RING_SIZE) {
            /* Full: keep the byte in DR (back-pressure) until the main loop makes room. */
            USART_CR1(LINK_BASE) &= ~USART_CR1_RXNEIE;
            NVIC_ICER(LINK_IRQn / 32u) = 1u << (LINK_IRQn % 32u);
            return;
        }
        rx_ring[head & (RX_RING_SIZE - 1u)] = (uint8_t)USART_DR(LINK_BASE);
        rx_head = head + 1u;
    }
}

size_t usart_rx_peek(const uint8_t **data)
{
    uint32_t tail = rx_tail;
    uint32_t avail = rx_head - tail;
    uint32_t start = tail & (RX_RING_SIZE - 1u);
    uint32_t run = RX_RING_SIZE - start;
    *data = &rx_ring[start];
    return (size_t)(avail < run ? avail : run);
}

size_t usart_rx_wait(const uint8_t **data)
{
    for (;;) {
        size_t n;
        cpu_irq_disable();
        n = usart_rx_peek(data);
        if (n != 0u) {
            cpu_irq_enable();
            return n;
        }
        /* Sleep with interrupts masked: a byte arriving between the check and WFI still wakes the
         * core (pending IRQ), and is handled once interrupts are re-enabled. */
        cpu_wfi();
        cpu_irq_enable();
    }
}

void usart_rx_release(size_t n)
{
    rx_tail += (uint32_t)n;
    if ((USART_CR1(LINK_BASE) & USART_CR1_RXNEIE) == 0u) {
        /* Read-modify-write of CR1 races only with the ISR clearing RXNEIE, which it does only
         * while RXNEIE is set; here it is clear, so the ISR cannot run. */
        USART_CR1(LINK_BASE) |= USART_CR1_RXNEIE;
        NVIC_ISER(LINK_IRQn / 32u) = 1u << (LINK_IRQn % 32u);
    }
}

uint32_t usart_rx_overruns(void) { return rx_overruns; }

void usart_write(const uint8_t *data, size_t n)
{
    size_t i;
    for (i = 0; i < n; i++) {
        while ((USART_SR(LINK_BASE) & USART_SR_TXE) == 0u) {
        }
        USART_DR(LINK_BASE) = data[i];
    }
}
