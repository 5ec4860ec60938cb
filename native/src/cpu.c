/* Which instruction set the compositor kernels run with, decided once per process.
 *
 * x86-64: the kernels are compiled three times (internal.h, SC_MULTIVERSION) for the
 * x86-64-v4 (AVX-512), x86-64-v3 (AVX2 + FMA) and baseline (SSE2) levels; the highest level the
 * CPU and the operating system both support is used. The features are those of the psABI levels
 * the compiler targets, read with cpuid; the OS must also save the wider registers (XCR0).
 * arm64: NEON is part of the baseline, so there is one build and nothing to pick.
 *
 * SPLATCORE_ISA=sse2|avx2|avx512 in the environment caps the level (never above what the CPU
 * has): for tests that compare the levels, and for ruling a level out when chasing a problem. */
#include "internal.h"

#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#if SC_MULTIVERSIONED
#include <cpuid.h>
#if defined(__APPLE__)
#include <sys/sysctl.h>
#endif

static void cpuid(unsigned leaf, unsigned sub, unsigned r[4]) {
    if (!__get_cpuid_count(leaf, sub, &r[0], &r[1], &r[2], &r[3])) r[0] = r[1] = r[2] = r[3] = 0;
}

static unsigned long long xcr0(void) {
    unsigned lo, hi;
    __asm__ volatile("xgetbv" : "=a"(lo), "=d"(hi) : "c"(0));
    return ((unsigned long long)hi << 32) | lo;
}

#if defined(__APPLE__)
/* macOS turns on the AVX-512 register state on first use, so XCR0 can say "off" on a CPU that
 * has it; the kernel's own flag is the documented test. */
static int apple_flag(const char *name) {
    int value = 0;
    size_t size = sizeof value;
    return sysctlbyname(name, &value, &size, NULL, 0) == 0 && value;
}
#endif

static sc_isa detect(void) {
    unsigned l1[4], l7[4], x1[4];
    cpuid(0, 0, l1);
    const unsigned max_leaf = l1[0];
    cpuid(1, 0, l1);
    if (max_leaf >= 7) cpuid(7, 0, l7);
    else l7[0] = l7[1] = l7[2] = l7[3] = 0;
    cpuid(0x80000001u, 0, x1);
    const unsigned ecx1 = l1[2], ebx7 = l7[1], ecx_x1 = x1[2];
    const int osxsave = (ecx1 >> 27) & 1;
    const unsigned long long xcr = osxsave ? xcr0() : 0;
    const int os_avx = (xcr & 0x6) == 0x6;      /* XMM and YMM state */
    const int os_avx512 = (xcr & 0xe6) == 0xe6; /* and opmask, ZMM_Hi256, Hi16_ZMM */
    const int v3 = os_avx && ((ecx1 >> 28) & 1)  /* AVX */ && ((ecx1 >> 12) & 1) /* FMA */ &&
                   ((ecx1 >> 29) & 1) /* F16C */ && ((ecx1 >> 22) & 1) /* MOVBE */ &&
                   ((ebx7 >> 5) & 1) /* AVX2 */ && ((ebx7 >> 3) & 1) /* BMI1 */ &&
                   ((ebx7 >> 8) & 1) /* BMI2 */ && ((ecx_x1 >> 5) & 1) /* LZCNT */;
    if (!v3) return SC_ISA_BASE;
    const int avx512 = ((ebx7 >> 16) & 1) /* F */ && ((ebx7 >> 17) & 1) /* DQ */ &&
                       ((ebx7 >> 28) & 1) /* CD */ && ((ebx7 >> 30) & 1) /* BW */ &&
                       ((ebx7 >> 31) & 1) /* VL */;
#if defined(__APPLE__)
    const int os_zmm = os_avx512 || apple_flag("hw.optional.avx512f");
#else
    const int os_zmm = os_avx512;
#endif
    return avx512 && os_zmm ? SC_ISA_V4 : SC_ISA_V3;
}
#else
static sc_isa detect(void) { return SC_ISA_BASE; }
#endif

static sc_isa capped(sc_isa isa) {
    const char *cap = getenv("SPLATCORE_ISA");
    if (!cap) return isa;
    const sc_isa limit = !strcmp(cap, "sse2") ? SC_ISA_BASE : !strcmp(cap, "avx2") ? SC_ISA_V3 : SC_ISA_V4;
    return isa < limit ? isa : limit;
}

static atomic_int chosen = -1;

sc_isa sc_cpu_isa(void) {
    int isa = atomic_load_explicit(&chosen, memory_order_relaxed);
    if (isa < 0) { /* a race only computes the same answer twice */
        isa = (int)capped(detect());
        atomic_store_explicit(&chosen, isa, memory_order_relaxed);
    }
    return (sc_isa)isa;
}

const char *sc_cpu_isa_name(void) {
#if SC_MULTIVERSIONED
    static const char *const names[] = {"sse2", "avx2", "avx512"};
    return names[sc_cpu_isa()];
#elif defined(__aarch64__) || defined(_M_ARM64)
    return "neon";
#else
    return "baseline";
#endif
}
