/* FMU states of a native uplift FMU: the whole state block (time, variables, held stamped
   inputs, stepper and soil) copied by Get/SetFMUstate (fmi2.c, fmi3.c: the entry points call
   the functions here), and serialised as

     offset  size  field
     0       8     magic "UPLIFTST" (uint64 0x55504c4946545354)
     8       4     format version, uint32 (UP_STATE_VERSION)
     12      4     CRC-32 (IEEE, as zlib's crc32) of every byte from offset 16 to the end, uint32
     16      8     identity of the FMU: a hash of its GUID, uint64
     24      8     length of the block in doubles, uint64
     32            the block

   A buffer that fails any check (size, magic, version, checksum, identity, length) is refused
   with an error and the reason in the log; nothing is allocated and the instance is unchanged. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmu.h"
#include "uplift_crc32.h"

#define STATE_MAGIC 0x55504c4946545354ULL      /* "UPLIFTST" */
#define SER_HEADER 32

typedef struct {
    uint64_t magic, guid_hash;
    size_t len;
    double data[1];
} State;

static State *checked_state(UpInstance *I, void *s, const char *fn)
{
    State *S = (State *)s;
    if (!S || S->magic != STATE_MAGIC || S->guid_hash != I->guid_hash || S->len != I->block_len) {
        up_log_error(I, "%s: not an FMU state of this FMU (get it from this FMU: get the FMU state, or "
                     "deserialise one)", fn);
        return NULL;
    }
    return S;
}

static State *new_state(UpInstance *I)
{
    State *S = (State *)malloc(sizeof(State) + I->block_len * sizeof(double));
    if (S) {
        S->magic = STATE_MAGIC;
        S->guid_hash = I->guid_hash;
        S->len = I->block_len;
    }
    return S;
}

int up_state_get(UpInstance *I, const char *fn, void **s)
{
    if (!s) {
        up_log_error(I, "%s: FMUstate pointer is NULL", fn);
        return -1;
    }
    State *S = (State *)*s;
    if (S && !checked_state(I, S, fn))
        return -1;
    if (!S && !(S = new_state(I))) {
        up_log_error(I, "%s: out of memory", fn);
        return -1;
    }
    memcpy(S->data, I->block, I->block_len * sizeof(double));
    *s = S;
    return 0;
}

int up_state_set(UpInstance *I, const char *fn, void *s)
{
    State *S = checked_state(I, s, fn);
    if (!S)
        return -1;
    memcpy(I->block, S->data, I->block_len * sizeof(double));
    return 0;
}

int up_state_free(UpInstance *I, const char *fn, void **s)
{
    if (!s) {
        up_log_error(I, "%s: FMUstate pointer is NULL", fn);
        return -1;
    }
    if (*s && !checked_state(I, *s, fn))
        return -1;
    if (*s)
        ((State *)*s)->magic = 0;
    free(*s);
    *s = NULL;
    return 0;
}

int up_state_size(UpInstance *I, const char *fn, void *s, size_t *size)
{
    if (!size) {
        up_log_error(I, "%s: size pointer is NULL", fn);
        return -1;
    }
    if (!checked_state(I, s, fn))
        return -1;
    *size = SER_HEADER + I->block_len * sizeof(double);
    return 0;
}

int up_state_serialize(UpInstance *I, const char *fn, void *s, unsigned char *b, size_t size)
{
    State *S = checked_state(I, s, fn);
    if (!S)
        return -1;
    if (!b || size != SER_HEADER + S->len * sizeof(double)) {
        up_log_error(I, "%s: give a buffer of the serialised state's size (SerializedFMUstateSize)", fn);
        return -1;
    }
    uint64_t magic = STATE_MAGIC, len = (uint64_t)S->len;
    uint32_t version = UP_STATE_VERSION;
    memcpy(b, &magic, 8);
    memcpy(b + 8, &version, 4);
    memcpy(b + 16, &S->guid_hash, 8);
    memcpy(b + 24, &len, 8);
    memcpy(b + SER_HEADER, S->data, S->len * sizeof(double));
    uint32_t crc = up_crc32(b + 16, size - 16);
    memcpy(b + 12, &crc, 4);
    return 0;
}

/* NULL, or why the bytes are not a serialised state of this instance's FMU (buf: 64 chars) */
static const char *state_fault(UpInstance *I, const unsigned char *b, size_t size, char *buf)
{
    uint64_t magic = 0, ident = 0, len = 0;
    uint32_t version = 0, crc = 0;
    if (size < SER_HEADER || (memcpy(&magic, b, 8), magic != STATE_MAGIC))
        return UP_MSG_STATE_MAGIC;
    memcpy(&version, b + 8, 4);
    memcpy(&crc, b + 12, 4);
    memcpy(&ident, b + 16, 8);
    memcpy(&len, b + 24, 8);
    if (version != UP_STATE_VERSION) {
        char v[32], e[32];
        snprintf(v, sizeof v, "%u", version);
        snprintf(e, sizeof e, "%d", UP_STATE_VERSION);
        snprintf(buf, 160, UP_MSG_STATE_VERSION, v, e);
        return buf;
    }
    if (up_crc32(b + 16, size - 16) != crc)
        return UP_MSG_STATE_CHECKSUM;
    if (ident != I->guid_hash) {
        char g[32], e[32];
        snprintf(g, sizeof g, "%016llx", (unsigned long long)ident);
        snprintf(e, sizeof e, "%016llx", (unsigned long long)I->guid_hash);
        snprintf(buf, 160, UP_MSG_STATE_IDENTITY, g, e);
        return buf;
    }
    if (len != I->block_len || size != SER_HEADER + I->block_len * sizeof(double))
        return UP_MSG_STATE_SIZE;
    return NULL;
}

int up_state_deserialize(UpInstance *I, const char *fn, const unsigned char *bytes, size_t size, void **s)
{
    char buf[160], sz[32];
    const char *why = !s || !bytes ? "NULL bytes or state pointer" : state_fault(I, bytes, size, buf);
    if (why) {
        snprintf(sz, sizeof sz, "%zu", size);
        up_log_error(I, "%s: " UP_MSG_BAD_STATE, fn, sz, why);
        return -1;
    }
    State *S = new_state(I);
    if (!S) {
        up_log_error(I, "%s: out of memory", fn);
        return -1;
    }
    memcpy(S->data, bytes + SER_HEADER, S->len * sizeof(double));
    *s = S;
    return 0;
}
