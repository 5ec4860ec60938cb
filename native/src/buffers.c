/* Reusable working buffers. A frame's working memory (about 130 bytes per Gaussian and 4 per
 * tile pair) is allocated at the start and freed at the end; from the operating system, fresh
 * pages cost a page fault and zeroing each (about 15% of a 1M-Gaussian frame). So freed blocks
 * of at least 1 MiB are kept, up to 16 of them (in practice the last frame's working memory and
 * images: sc_image_alloc), and handed out again to requests they fit within a factor of 2.
 * sc_release_buffers() returns them.
 *
 * Every block carries a 64-byte header holding its capacity, so the memory after it is
 * aligned for the 64-byte splat records. */
#include <stdatomic.h>
#include <stdlib.h>

#include "internal.h"

enum { HEADER = 64, KEPT = 16 };
static const size_t MIN_KEPT = (size_t)1 << 20;

static struct {
    atomic_flag lock;
    unsigned char *blocks[KEPT]; /* headers of kept blocks, or NULL */
} cache = {.lock = ATOMIC_FLAG_INIT};

static void lock(void) {
    while (atomic_flag_test_and_set_explicit(&cache.lock, memory_order_acquire)) {
    }
}

static void unlock(void) { atomic_flag_clear_explicit(&cache.lock, memory_order_release); }

static size_t capacity(const unsigned char *header) {
    size_t bytes;
    memcpy(&bytes, header, sizeof bytes);
    return bytes;
}

void *sc_buffer_alloc(size_t bytes) {
    if (bytes == 0) bytes = 1;
    if (bytes >= MIN_KEPT) {
        lock();
        int best = -1;
        for (int k = 0; k < KEPT; ++k) {
            const unsigned char *b = cache.blocks[k];
            if (b && capacity(b) >= bytes && capacity(b) / 2 <= bytes &&
                (best < 0 || capacity(b) < capacity(cache.blocks[best])))
                best = k;
        }
        unsigned char *found = best >= 0 ? cache.blocks[best] : NULL;
        if (found) cache.blocks[best] = NULL;
        unlock();
        if (found) return found + HEADER;
    }
    if (bytes > SIZE_MAX - HEADER) return NULL;
    unsigned char *header = malloc(bytes + HEADER);
    if (!header) return NULL;
    memcpy(header, &bytes, sizeof bytes);
    return header + HEADER;
}

void sc_buffer_free(void *p) {
    if (!p) return;
    unsigned char *header = (unsigned char *)p - HEADER;
    if (capacity(header) >= MIN_KEPT) {
        lock();
        /* Keep it in a free slot, or in place of the smallest kept block if it is larger. */
        int slot = -1;
        for (int k = 0; k < KEPT && slot < 0; ++k)
            if (!cache.blocks[k]) slot = k;
        if (slot < 0) {
            slot = 0;
            for (int k = 1; k < KEPT; ++k)
                if (capacity(cache.blocks[k]) < capacity(cache.blocks[slot])) slot = k;
            if (capacity(cache.blocks[slot]) >= capacity(header)) slot = -1;
        }
        unsigned char *evicted = NULL;
        if (slot >= 0) {
            evicted = cache.blocks[slot];
            cache.blocks[slot] = header;
            header = evicted;
        }
        unlock();
    }
    free(header);
}

void *sc_image_alloc(size_t bytes) { return sc_buffer_alloc(bytes); }

void sc_image_free(void *p) { sc_buffer_free(p); }

void sc_release_buffers(void) {
    unsigned char *blocks[KEPT];
    lock();
    for (int k = 0; k < KEPT; ++k) blocks[k] = cache.blocks[k], cache.blocks[k] = NULL;
    unlock();
    for (int k = 0; k < KEPT; ++k) free(blocks[k]);
}
