/* What the plain C test hosts (host.c: FMI 2.0, host3.c: FMI 3.0) share: an allocation counter
   and the loader of the FMU's symbols. Included once by each host, after its FMI header. */
#ifndef HOST_COMMON_H
#define HOST_COMMON_H

#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>

/* ---- allocations inside a window (glibc: the executable's malloc interposes the library's) -- */
extern void *__libc_malloc(size_t);
extern void *__libc_calloc(size_t, size_t);
extern void *__libc_realloc(void *, size_t);
static int counting;
static long allocations;

void *malloc(size_t n)
{
    allocations += counting;
    return __libc_malloc(n);
}

void *calloc(size_t n, size_t m)
{
    allocations += counting;
    return __libc_calloc(n, m);
}

void *realloc(void *p, size_t n)
{
    allocations += counting;
    return __libc_realloc(p, n);
}

/* ---- the FMU's library and its functions ----------------------------------------------------- */
static void *lib;
#define FN(name) static name##TYPE *name;

static void *sym(const char *name)
{
    void *f = dlsym(lib, name);
    if (!f) {
        fprintf(stderr, "missing %s\n", name);
        exit(3);
    }
    return f;
}

#define LOAD(name) name = (name##TYPE *)sym(#name);

static void open_library(const char *path)
{
    lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        fprintf(stderr, "dlopen: %s\n", dlerror());
        exit(2);
    }
}

#endif
