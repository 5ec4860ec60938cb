/* A checksum of raw memory (sc_checksum, splatcore.h): F12's test whether a splat object's
 * attributes changed since the last render (addon/blender/gather.py), read where Blender keeps
 * them. zlib's CRC-32 took 4.5 to 7 ms over PLAYBOT's 19 MB; this runs at memory speed.
 *
 * The memory is read as 64-bit words w_i (the tail zero-padded); lane i mod 4 adds up
 * mix(w_i xor i * golden), where mix is MurmurHash3's 64-bit finaliser, a bijection: so changing
 * one word always changes its lane's sum, and a change within any 193 consecutive bits (at most
 * one word per lane) always changes the checksum. Other changes go unnoticed only if all four
 * sums stay the same. Words are loaded in the machine's byte order: a key for this process, not
 * a file format. */
#include <string.h>

#include "internal.h"

static SC_ALWAYS_INLINE uint64_t mix(uint64_t x) {
    x ^= x >> 33;
    x *= 0xff51afd7ed558ccdULL;
    x ^= x >> 33;
    x *= 0xc4ceb9fe1a85ec53ULL;
    x ^= x >> 33;
    return x;
}

static const uint64_t GOLDEN = 0x9e3779b97f4a7c15ULL;

static SC_ALWAYS_INLINE void sums(const unsigned char *data, int64_t bytes, uint64_t out[4]) {
    uint64_t lane[4] = {0, 0, 0, 0};
    const int64_t words = bytes / 8, blocks = words / 4;
    for (int64_t b = 0; b < blocks; ++b) {
        uint64_t w[4];
        memcpy(w, data + 32 * b, sizeof w);
        for (int k = 0; k < 4; ++k) lane[k] += mix(w[k] ^ (uint64_t)(4 * b + k) * GOLDEN);
    }
    for (int64_t i = 4 * blocks; i * 8 < bytes; ++i) { /* the last words, the tail padded */
        uint64_t w = 0;
        const int64_t left = bytes - 8 * i;
        memcpy(&w, data + 8 * i, (size_t)(left < 8 ? left : 8));
        lane[i & 3] += mix(w ^ (uint64_t)i * GOLDEN);
    }
    (void)words;
    memcpy(out, lane, sizeof lane);
}

SC_MULTIVERSION(void, sums_isa, (const unsigned char *data, int64_t bytes, uint64_t *out),
                (data, bytes, out), sums(data, bytes, out))

void sc_checksum(const void *data, int64_t bytes, uint64_t out[4]) {
    sums_isa(data, bytes, out);
}
