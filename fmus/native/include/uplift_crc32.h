/* CRC-32 (IEEE 802.3, reflected, as zlib's crc32), bitwise: a few MB/s is plenty for a state.
 * One definition for the native runtime (state.c: the serialised FMU state) and the python
 * FMUs' guard (fmus/pyguard_c/guard.c: the same check of serialised bytes), which are compiled
 * apart: static inline, so neither exports a symbol for it. */
#ifndef UPLIFT_CRC32_H
#define UPLIFT_CRC32_H

#include <stddef.h>
#include <stdint.h>

static inline uint32_t up_crc32(const unsigned char *p, size_t n)
{
    uint32_t c = 0xFFFFFFFFu;
    for (size_t i = 0; i < n; i++) {
        c ^= p[i];
        for (int k = 0; k < 8; k++)
            c = (c >> 1) ^ (0xEDB88320u & (0u - (c & 1u)));
    }
    return c ^ 0xFFFFFFFFu;
}

#endif
