/* The binary resource file (resources/uplift.bin): read whole, checked (magic, version, size,
   checksum, every record's extent), records found by name. Format: README.md beside this file. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "uplift.h"

#define HEADER 32
#define RECORD 80
static const char MAGIC[8] = {'U', 'P', 'L', 'I', 'F', 'T', 'N', 'B'};
enum { VERSION = 1 };

static uint32_t rd32(const unsigned char *p) { uint32_t v; memcpy(&v, p, 4); return v; }
static uint64_t rd64(const unsigned char *p) { uint64_t v; memcpy(&v, p, 8); return v; }

/* CRC-32 (IEEE 802.3, as zlib's crc32), eight bytes per table round ("slicing by 8": t[k][b]
   is the CRC of byte b followed by k zero bytes), so that checking a model of a few MB is a
   small part of the instantiation */
static uint32_t crc32(const unsigned char *p, size_t n)
{
    uint32_t t[8][256];                  /* built per call: no shared state between threads */
    for (uint32_t i = 0; i < 256; i++) {
        uint32_t c = i;
        for (int k = 0; k < 8; k++)
            c = c & 1 ? 0xEDB88320u ^ (c >> 1) : c >> 1;
        t[0][i] = c;
    }
    for (int k = 1; k < 8; k++)
        for (int i = 0; i < 256; i++)
            t[k][i] = (t[k - 1][i] >> 8) ^ t[0][t[k - 1][i] & 0xFF];
    uint32_t c = 0xFFFFFFFFu;
    for (; n >= 8; n -= 8, p += 8) {
        uint32_t lo = c ^ ((uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24);
        c = t[7][lo & 0xFF] ^ t[6][(lo >> 8) & 0xFF] ^ t[5][(lo >> 16) & 0xFF] ^ t[4][lo >> 24] ^ t[3][p[4]]
            ^ t[2][p[5]] ^ t[1][p[6]] ^ t[0][p[7]];
    }
    for (; n > 0; n--, p++)
        c = t[0][(c ^ *p) & 0xFF] ^ (c >> 8);
    return c ^ 0xFFFFFFFFu;
}

static int parse(UpRes *r, size_t size, char *err);

static int fail(UpRes *r, char *err, const char *what)
{
    snprintf(err, UP_MSG, "resource file %s %s: export the FMU again (uplift export)", r->path, what);
    up_res_free(r);
    return -1;
}

int up_res_load(UpRes *r, const char *path, char *err)
{
    const uint16_t probe = 1;
    memset(r, 0, sizeof *r);
    snprintf(r->path, sizeof r->path, "%s", path);
    if (*(const unsigned char *)&probe != 1)
        return fail(r, err, "is little-endian: this host is big-endian, which the runtime does not read");
    FILE *f = fopen(path, "rb");
    if (!f)
        return fail(r, err, "cannot be opened (is the resources folder of the FMU there?)");
    long size = -1;
    if (fseek(f, 0, SEEK_END) == 0)
        size = ftell(f);
    if (size < HEADER || fseek(f, 0, SEEK_SET) != 0) {
        fclose(f);
        return fail(r, err, "is too short");
    }
    r->buf = (unsigned char *)malloc((size_t)size);
    if (!r->buf) {
        fclose(f);
        return fail(r, err, "does not fit in memory");
    }
    size_t got = fread(r->buf, 1, (size_t)size, f);
    fclose(f);
    if (got != (size_t)size)
        return fail(r, err, "cannot be read");
    return parse(r, (size_t)size, err);
}

int up_res_parse(UpRes *r, const unsigned char *data, size_t size, const char *name, char *err)
{
    memset(r, 0, sizeof *r);
    snprintf(r->path, sizeof r->path, "%s", name);
    if (size < HEADER)
        return fail(r, err, "is too short");
    r->buf = (unsigned char *)malloc(size);
    if (!r->buf)
        return fail(r, err, "does not fit in memory");
    memcpy(r->buf, data, size);
    return parse(r, size, err);
}

/* the checks and the record table of the file read whole into r->buf (size bytes) */
static int parse(UpRes *r, size_t size, char *err)
{
    const unsigned char *b = r->buf;
    if (memcmp(b, MAGIC, 8) != 0)
        return fail(r, err, "is not an uplift resource file");
    if (rd32(b + 8) != VERSION)
        return fail(r, err, "has another format version than this runtime");
    if (rd64(b + 16) != (uint64_t)size)
        return fail(r, err, "is truncated");
    if (rd32(b + 24) != crc32(b + HEADER, (size_t)size - HEADER))
        return fail(r, err, "is damaged (checksum)");
    uint32_t count = rd32(b + 12);
    if (count > 4096)
        return fail(r, err, "has too many records");
    r->rec = (UpRecord *)calloc(count ? count : 1, sizeof(UpRecord));
    if (!r->rec)
        return fail(r, err, "does not fit in memory");
    size_t off = HEADER;
    for (uint32_t i = 0; i < count; i++) {
        UpRecord *rec = &r->rec[i];
        if (off + RECORD > (size_t)size)
            return fail(r, err, "is truncated (record header)");
        memcpy(rec->name, b + off, 32);
        rec->name[32] = '\0';
        rec->kind = (int)rd32(b + off + 32);
        rec->ndim = (int)rd32(b + off + 36);
        rec->nbytes = rd64(b + off + 72);
        if (rec->ndim < 0 || rec->ndim > 4)
            return fail(r, err, "has a record with more than 4 dimensions");
        uint64_t count_el = 1;
        for (int k = 0; k < 4; k++) {
            rec->dims[k] = (int64_t)rd64(b + off + 40 + 8 * k);
            if (k < rec->ndim) {
                if (rec->dims[k] < 0 || rec->dims[k] > ((int64_t)1 << 40))
                    return fail(r, err, "has a record with a bad shape");
                count_el *= (uint64_t)rec->dims[k];
            }
        }
        uint64_t expect = rec->kind == UP_TEXT ? count_el : 8 * count_el;
        if ((rec->kind != UP_F64 && rec->kind != UP_I64 && rec->kind != UP_TEXT) || rec->nbytes != expect
            || (rec->kind == UP_TEXT && rec->ndim != 1))
            return fail(r, err, "has a record whose size does not match its shape");
        off += RECORD;
        uint64_t padded = (rec->nbytes + 7) / 8 * 8;
        if (padded > (uint64_t)size - off)
            return fail(r, err, "is truncated (record data)");
        rec->data = b + off;
        off += (size_t)padded;
    }
    if (off != (size_t)size)
        return fail(r, err, "has trailing bytes");
    r->count = (int)count;
    return 0;
}

void up_res_free(UpRes *r)
{
    free(r->rec);
    free(r->buf);
    r->rec = NULL;
    r->buf = NULL;
    r->count = 0;
}

const UpRecord *up_res_find(const UpRes *r, const char *name)
{
    for (int i = 0; i < r->count; i++)
        if (strcmp(r->rec[i].name, name) == 0)
            return &r->rec[i];
    return NULL;
}

static const void *typed(const UpRes *r, const char *name, int kind, int ndim, int64_t *dims, char *err)
{
    const UpRecord *rec = up_res_find(r, name);
    const char *what = kind == UP_F64 ? "float64" : "int64";
    if (!rec) {
        snprintf(err, UP_MSG, "resource file %s has no record %s: export the FMU again with this "
                 "version of uplift", r->path, name);
        return NULL;
    }
    int ok = rec->kind == kind && rec->ndim == ndim;
    for (int k = 0; ok && k < ndim; k++)
        ok = dims[k] < 0 || dims[k] == rec->dims[k];
    if (!ok) {
        snprintf(err, UP_MSG, "resource file %s: record %s is not the %d-dimensional %s array of the "
                 "expected shape: export the FMU again with this version of uplift", r->path, name, ndim, what);
        return NULL;
    }
    for (int k = 0; k < ndim; k++)
        dims[k] = rec->dims[k];
    return rec->data;
}

const double *up_res_f64(const UpRes *r, const char *name, int ndim, int64_t *dims, char *err)
{
    return (const double *)typed(r, name, UP_F64, ndim, dims, err);
}

const int64_t *up_res_i64(const UpRes *r, const char *name, int ndim, int64_t *dims, char *err)
{
    return (const int64_t *)typed(r, name, UP_I64, ndim, dims, err);
}

int up_res_scalar(const UpRes *r, const char *name, double *value, char *err)
{
    const double *v = up_res_f64(r, name, 0, NULL, err);
    if (!v)
        return -1;
    *value = v[0];
    return 0;
}
