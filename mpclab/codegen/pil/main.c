/* PIL harness: the generated controller on recorded states. Each step runs between the calls
 * pil_begin() and pil_end() (kept out of line, so an instruction trace can find them); its
 * result goes to the console as hex bit patterns, which the host compares with the desktop C.
 * Included after the controller's source and the recorded states (pil_x, pil_ref, PIL_N). */
void pil_puts(const char *s);

__attribute__((noinline)) void pil_begin(void) { __asm__ volatile("" ::: "memory"); }
__attribute__((noinline)) void pil_end(void) { __asm__ volatile("" ::: "memory"); }

static char *pil_hex(char *p, unsigned long long v, int digits)
{
    int i;
    for (i = digits - 1; i >= 0; --i) *p++ = "0123456789abcdef"[(v >> (4 * i)) & 15u];
    *p++ = ' ';
    return p;
}

static void pil_print(int op, int rc, int iters, const mpc_real z[MPC_NZ])
{
    char line[32 + MPC_NZ * 17], *p = line;
    int i;
    p = pil_hex(p, (unsigned)op, 2);
    p = pil_hex(p, (unsigned)rc, 2);
    p = pil_hex(p, (unsigned)iters, 4);
    for (i = 0; i < MPC_NZ; ++i) {
        union { mpc_real r; unsigned long long u; } bits;
        bits.u = 0;
        bits.r = z[i];
        p = pil_hex(p, bits.u, (int)(2 * sizeof(mpc_real)));
    }
    p[-1] = '\n';
    *p = 0;
    pil_puts(line);
}

int main(void)
{
    static mpc_real x[MPC_NX], ref[MPC_NREF], z[MPC_NZ];
    int n, i, op, rc, iters;
    for (n = 0; n < PIL_N; ++n) {
        for (i = 0; i < MPC_NX; ++i) x[i] = (mpc_real)pil_x[n][i];
        for (i = 0; i < MPC_NREF; ++i) ref[i] = (mpc_real)pil_ref[n][i];
        pil_begin();
        rc = mpc_step(x, ref, z, &op, &iters);
        pil_end();
        pil_print(op, rc, iters, z);
    }
    pil_puts("done\n");
    return 0;
}
