/* Text on the link (the fault report, the self-test banner): built on usart_write(), shared by the
 * USART link (usart.c) and the emulator's semihosting link (semihost_link.c). */
#include "board.h"

void usart_puts(const char *s)
{
    size_t n = 0;
    while (s[n] != '\0') {
        n++;
    }
    usart_write((const uint8_t *)s, n);
}

void usart_put_hex32(uint32_t v)
{
    static const char digits[] = "0123456789abcdef";
    uint8_t buf[10];
    unsigned i;
    buf[0] = '0';
    buf[1] = 'x';
    for (i = 0; i < 8u; i++) {
        buf[2u + i] = (uint8_t)digits[(v >> (28u - 4u * i)) & 0xFu];
    }
    usart_write(buf, sizeof buf);
}
