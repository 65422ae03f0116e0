/* Bare-metal start for the PIL build: vector table, .data/.bss set-up, the FPU switched on,
 * and semihosting (ARM's "bkpt 0xAB" calls) for the console and the exit. No C library I/O. */
#include <stdint.h>

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;
int main(void);
void pil_reset(void);

static void pil_hang(void) { for (;;) {} }

__attribute__((section(".isr_vector"), used))
static const void *const pil_vectors[16] = {
    &_estack, (const void *)pil_reset, (const void *)pil_hang, (const void *)pil_hang,
    (const void *)pil_hang, (const void *)pil_hang, (const void *)pil_hang,
};

int pil_semihost(int op, const void *arg)
{
    register int r0 __asm__("r0") = op;
    register const void *r1 __asm__("r1") = arg;
    __asm__ volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
    return r0;
}

void pil_puts(const char *s) { pil_semihost(0x04, s); /* SYS_WRITE0 */ }

void pil_reset(void)
{
    uint32_t *src = &_sidata, *dst = &_sdata;
    while (dst < &_edata) *dst++ = *src++;
    for (dst = &_sbss; dst < &_ebss;) *dst++ = 0;
    *(volatile uint32_t *)0xE000ED88 |= 0xFu << 20; /* CPACR: CP10, CP11 full access */
    __asm__ volatile("dsb\n\tisb");
    main();
    pil_semihost(0x18, (const void *)0x20026); /* SYS_EXIT, ADP_Stopped_ApplicationExit */
    pil_hang();
}
