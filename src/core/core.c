/*
 * core.c: context lifetime, the error message slot, allocation hooks, result and version names.
 * No global mutable state: everything lives in the nacre_context.
 */
#define _DEFAULT_SOURCE 1 /* madvise's MADV_HUGEPAGE (glibc); the build asks for POSIX 2008 only */
#include "core/core.h"

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <sys/resource.h>
#include <unistd.h>
#ifdef _OPENMP
#include <omp.h>
#endif

#ifndef NACRE_VERSION_STRING /* set by the build; the fallback keeps stand-alone syntax checks working */
#define NACRE_VERSION_STRING "0.1.0"
#endif

#if defined(__linux__)
#include <sys/mman.h>
#endif

/* Blocks of at least this size are frame-sized buffers (G-buffer planes, shadow maps, images,
 * voxel grids) that the passes sweep every frame: the default allocator asks Linux to back them
 * with 2 MB pages. With 4 KB pages these sweeps miss the TLB on every page, and on a virtual
 * machine each miss is a two-level page walk: the huge pages took the shading pass, the shadow
 * map, the G-buffer and the visibility pass of Suzanne's bench frame 4-9% faster. A caller's own
 * allocator is left alone. */
#define HUGE_PAGE_MIN (4u << 20)

static void *default_alloc(size_t size, void *user)
{
    (void)user;
    void *p = malloc(size);
#if defined(__linux__) && defined(MADV_HUGEPAGE)
    if (p && size >= HUGE_PAGE_MIN) {
        /* The whole 2 MB pages inside the block; only advice, so a refusal changes nothing */
        const uintptr_t page = (uintptr_t)2 << 20;
        const uintptr_t lo = ((uintptr_t)p + page - 1) & ~(page - 1), hi = ((uintptr_t)p + size) & ~(page - 1);
        if (hi > lo)
            (void)madvise((void *)lo, (size_t)(hi - lo), MADV_HUGEPAGE);
    }
#endif
    return p;
}

static void default_free(void *ptr, void *user)
{
    (void)user;
    free(ptr);
}

/* Half of physical memory: room for the rest of the process and the system. When the address
 * space is limited (RLIMIT_AS, `ulimit -v`), three quarters of what is left of it now, since
 * the libraries, thread stacks and the mesh importer's copies live there too. */
static uint64_t default_memory_limit(void)
{
    uint64_t limit = (uint64_t)4 << 30; /* if the system does not say */
    long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGESIZE);
    if (pages > 0 && page > 0)
        limit = (uint64_t)pages * (uint64_t)page / 2;
    struct rlimit rl;
    if (getrlimit(RLIMIT_AS, &rl) == 0 && rl.rlim_cur != RLIM_INFINITY) {
        uint64_t vm = 0;
        FILE *f = fopen("/proc/self/statm", "r");
        unsigned long long vm_pages = 0;
        if (f) {
            if (fscanf(f, "%llu", &vm_pages) == 1 && page > 0)
                vm = vm_pages * (uint64_t)page;
            fclose(f);
        }
        uint64_t room = (uint64_t)rl.rlim_cur > vm ? (uint64_t)rl.rlim_cur - vm : 0;
        if (room / 4 * 3 < limit)
            limit = room / 4 * 3;
    }
    return limit > ((uint64_t)1 << 20) ? limit : ((uint64_t)1 << 20);
}

const char *nacre_version(void) { return NACRE_VERSION_STRING; }

const char *nacre_result_string(nacre_result result)
{
    switch (result) {
#define NACRE_RESULT_CASE_(name, value, text) case name: return text;
        NACRE_RESULT_LIST(NACRE_RESULT_CASE_)
#undef NACRE_RESULT_CASE_
    }
    return "unknown result";
}

nacre_result nacre_context_create(const nacre_context_desc *desc, nacre_context **out)
{
    if (!out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    *out = NULL;
    nacre_context_desc d = {0};
    if (desc)
        d = *desc;
    if ((d.allocator.alloc_fn == NULL) != (d.allocator.free_fn == NULL))
        return NACRE_ERROR_INVALID_ARGUMENT; /* both hooks or neither */
    if (!d.allocator.alloc_fn) {
        d.allocator.alloc_fn = default_alloc;
        d.allocator.free_fn = default_free;
    }
    if (d.threads < 0)
        return NACRE_ERROR_INVALID_ARGUMENT;
    nacre_context *ctx = d.allocator.alloc_fn(sizeof(*ctx), d.allocator.user);
    if (!ctx)
        return NACRE_ERROR_OUT_OF_MEMORY;
    memset(ctx, 0, sizeof(*ctx));
    ctx->allocator = d.allocator;
    ctx->log_fn = d.log_fn;
    ctx->log_user = d.log_user;
    int threads = d.threads;
#ifdef _OPENMP
    if (threads == 0)
        threads = omp_get_max_threads();
#else
    threads = 1;
#endif
    ctx->threads = threads < 1 ? 1 : threads;
    ctx->memory_limit = d.memory_limit ? d.memory_limit : default_memory_limit();
    pthread_mutex_init(&ctx->lock, NULL);
    *out = ctx;
    return NACRE_OK;
}

void nacre_context_destroy(nacre_context *ctx)
{
    if (!ctx)
        return;
    pthread_mutex_destroy(&ctx->lock);
    ctx->allocator.free_fn(ctx, ctx->allocator.user);
}

/* The calling thread's slot, or NULL. Called with the lock held. */
static nc_error_slot *thread_slot(const nacre_context *ctx)
{
    pthread_t self = pthread_self();
    for (int i = 0; i < NC_ERROR_SLOTS; i++)
        if (ctx->errors[i].used && pthread_equal(ctx->errors[i].thread, self))
            return (nc_error_slot *)&ctx->errors[i];
    return NULL;
}

const char *nacre_context_last_error(const nacre_context *ctx)
{
    if (!ctx)
        return "no context";
    pthread_mutex_lock((pthread_mutex_t *)&ctx->lock);
    const nc_error_slot *slot = thread_slot(ctx);
    pthread_mutex_unlock((pthread_mutex_t *)&ctx->lock);
    return slot ? slot->message : "";
}

nacre_result nacre_context_last_result(const nacre_context *ctx)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    pthread_mutex_lock((pthread_mutex_t *)&ctx->lock);
    const nc_error_slot *slot = thread_slot(ctx);
    nacre_result r = slot ? slot->result : NACRE_OK;
    pthread_mutex_unlock((pthread_mutex_t *)&ctx->lock);
    return r;
}

void nacre_context_clear_error(nacre_context *ctx)
{
    if (!ctx)
        return;
    pthread_mutex_lock(&ctx->lock);
    nc_error_slot *slot = thread_slot(ctx);
    if (slot) {
        slot->result = NACRE_OK;
        slot->message[0] = '\0';
    }
    pthread_mutex_unlock(&ctx->lock);
}

int nacre_context_threads(const nacre_context *ctx) { return ctx ? ctx->threads : 1; }

void nacre_free(nacre_context *ctx, void *ptr)
{
    if (ctx)
        nc_free(ctx, ptr);
}

uint64_t nacre_context_memory_limit(const nacre_context *ctx) { return ctx ? ctx->memory_limit : 0; }

nacre_result nacre_context_set_memory_limit(nacre_context *ctx, uint64_t bytes)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    ctx->memory_limit = bytes ? bytes : default_memory_limit();
    return NACRE_OK;
}

uint64_t nacre_context_memory_used(const nacre_context *ctx)
{
    return ctx ? atomic_load_explicit(&ctx->memory_used, memory_order_relaxed) : 0;
}

uint64_t nacre_context_memory_peak(const nacre_context *ctx)
{
    return ctx ? atomic_load_explicit(&ctx->memory_peak, memory_order_relaxed) : 0;
}

/* Messages quote names and strings from the files they describe, which may hold newlines or
 * other control characters; the API promises one printable line, so those become '?'. */
static void one_line(char *msg, size_t cap)
{
    for (char *c = msg; *c; c++)
        if ((unsigned char)*c < 0x20 || *c == 0x7f)
            *c = '?';
    if (!msg[0])
        snprintf(msg, cap, "unspecified error");
}

nacre_result nc_failv(nacre_context *ctx, nacre_result code, const char *fmt, va_list ap)
{
    if (!ctx)
        return code;
    char msg[NC_ERROR_MAX];
    vsnprintf(msg, sizeof(msg), fmt, ap);
    one_line(msg, sizeof(msg));
    pthread_mutex_lock(&ctx->lock);
    nc_error_slot *slot = thread_slot(ctx);
    if (!slot) { /* a free slot, else the least recently written */
        slot = &ctx->errors[0];
        for (int i = 0; i < NC_ERROR_SLOTS && slot->used; i++)
            if (!ctx->errors[i].used || ctx->errors[i].seq < slot->seq)
                slot = &ctx->errors[i];
        slot->used = true;
        slot->thread = pthread_self();
    }
    slot->seq = ++ctx->error_seq;
    slot->result = code;
    memcpy(slot->message, msg, sizeof(msg));
    pthread_mutex_unlock(&ctx->lock);
    if (ctx->log_fn)
        ctx->log_fn(ctx->log_user, NACRE_LOG_ERROR, msg);
    return code;
}

nacre_result nc_fail(nacre_context *ctx, nacre_result code, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    nc_failv(ctx, code, fmt, ap);
    va_end(ap);
    return code;
}

void nc_warn(nacre_context *ctx, const char *fmt, ...)
{
    if (!ctx || !ctx->log_fn)
        return;
    char msg[NC_ERROR_MAX];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof(msg), fmt, ap);
    va_end(ap);
    one_line(msg, sizeof(msg));
    ctx->log_fn(ctx->log_user, NACRE_LOG_WARNING, msg);
}

/* Each block carries its size and its context in a header, so that nc_free gives it back to
 * the count of the context that made it (callers with two contexts on one allocator may free
 * through either); 16 bytes keep the alignment malloc gives (the kernels use unaligned loads or
 * align at run time). */
#define BLOCK_HEADER 16u
_Static_assert(sizeof(uint64_t) + sizeof(void *) <= BLOCK_HEADER, "block header holds a size and a context");

static const char *limit_hint = "raise it with --memory-limit or nacre_context_desc.memory_limit";

const char *nc_format_bytes(uint64_t bytes, char *buf, size_t size)
{
    static const char *unit[] = {"bytes", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"};
    double v = (double)bytes;
    int u = 0;
    while (v >= 1024.0 && u < 6) {
        v /= 1024.0;
        u++;
    }
    if (u == 0)
        snprintf(buf, size, "%llu bytes", (unsigned long long)bytes);
    else
        snprintf(buf, size, "%.*f %s", v < 10.0 ? 2 : 1, v, unit[u]);
    return buf;
}

nacre_result nc_memory_check(nacre_context *ctx, uint64_t bytes, const char *what)
{
    uint64_t used = atomic_load_explicit(&ctx->memory_used, memory_order_relaxed);
    if (bytes <= ctx->memory_limit && used <= ctx->memory_limit - bytes)
        return NACRE_OK;
    char need[32], lim[32], held[32];
    return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "%s needs %s, over the memory limit of %s with %s held (%s)",
                   what, nc_format_bytes(bytes, need, sizeof(need)),
                   nc_format_bytes(ctx->memory_limit, lim, sizeof(lim)), nc_format_bytes(used, held, sizeof(held)),
                   limit_hint);
}

bool nc_reserve(nacre_context *ctx, void *slot, size_t *capacity, size_t count, size_t size)
{
    if (count <= *capacity)
        return true;
    if (size && count > SIZE_MAX / size) {
        nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "out of memory: %zu elements of %zu bytes", count, size);
        return false;
    }
    void *grown = nc_alloc(ctx, count * size);
    if (!grown)
        return false;
    /* The slot holds some T *; its bytes are moved as a void * (same representation). */
    void *old;
    memcpy(&old, slot, sizeof(old));
    nc_free(ctx, old);
    memcpy(slot, &grown, sizeof(grown));
    *capacity = count;
    return true;
}

void *nc_alloc(nacre_context *ctx, size_t size)
{
    char a[32], b[32];
    if (size > SIZE_MAX - BLOCK_HEADER) {
        nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "allocation of %s overflows", nc_format_bytes(size, a, sizeof(a)));
        return NULL;
    }
    const uint64_t total = (uint64_t)size + BLOCK_HEADER;
    /* Reserve first, so that threads allocating at once cannot pass the limit together. */
    uint64_t before = atomic_fetch_add_explicit(&ctx->memory_used, total, memory_order_relaxed);
    if (before + total > ctx->memory_limit || before + total < before) {
        atomic_fetch_sub_explicit(&ctx->memory_used, total, memory_order_relaxed);
        nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "allocation of %s is over the memory limit of %s (%s)",
                nc_format_bytes(size, a, sizeof(a)), nc_format_bytes(ctx->memory_limit, b, sizeof(b)),
                limit_hint);
        return NULL;
    }
    unsigned char *p = ctx->allocator.alloc_fn((size_t)total, ctx->allocator.user);
    if (!p) {
        atomic_fetch_sub_explicit(&ctx->memory_used, total, memory_order_relaxed);
        nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "out of memory: the system refused %s",
                nc_format_bytes(size, a, sizeof(a)));
        return NULL;
    }
    uint64_t now = before + total, peak = atomic_load_explicit(&ctx->memory_peak, memory_order_relaxed);
    while (now > peak &&
           !atomic_compare_exchange_weak_explicit(&ctx->memory_peak, &peak, now, memory_order_relaxed,
                                                  memory_order_relaxed)) {
    }
    memcpy(p, &total, sizeof(total));
    memcpy(p + sizeof(total), &ctx, sizeof(ctx));
    return p + BLOCK_HEADER;
}

void *nc_calloc(nacre_context *ctx, size_t count, size_t size)
{
    size_t bytes;
    if (!nc_mul_size_ok(count, size, &bytes)) {
        nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "allocation size overflows (%zu x %zu)", count, size);
        return NULL;
    }
    void *p = nc_alloc(ctx, bytes);
    if (p)
        memset(p, 0, bytes);
    return p;
}

void nc_free(nacre_context *ctx, void *ptr)
{
    if (!ptr)
        return;
    unsigned char *p = (unsigned char *)ptr - BLOCK_HEADER;
    uint64_t total;
    nacre_context *owner;
    memcpy(&total, p, sizeof(total));
    memcpy(&owner, p + sizeof(total), sizeof(owner));
    atomic_fetch_sub_explicit(&owner->memory_used, total, memory_order_relaxed);
    ctx->allocator.free_fn(p, ctx->allocator.user);
}

void *nc_realloc(nacre_context *ctx, void *ptr, size_t old_size, size_t new_size)
{
    void *p = nc_alloc(ctx, new_size);
    if (!p)
        return NULL;
    if (ptr) {
        memcpy(p, ptr, old_size < new_size ? old_size : new_size);
        nc_free(ctx, ptr);
    }
    return p;
}

char *nc_strdup(nacre_context *ctx, const char *s)
{
    size_t n = strlen(s) + 1;
    char *p = nc_alloc(ctx, n);
    if (p)
        memcpy(p, s, n);
    return p;
}

uint64_t nc_now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000u + (uint64_t)ts.tv_nsec / 1000u;
}
