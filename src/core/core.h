/*
 * core.h: the context (allocator, thread count, error message), checked size arithmetic and
 * timing shared by every module. Private to the library (prefix nc_).
 *
 * Error convention: a failing function calls nc_fail() once with the most specific message it
 * has ("file:line:col: field: problem"), and callers pass the code up without adding text.
 */
#ifndef NACRE_CORE_H
#define NACRE_CORE_H

#include <nacre/nacre.h>

#include <pthread.h>
#include <stdatomic.h>
#include <stdarg.h>
#include <stdint.h>
#include <string.h>

#define NC_ERROR_MAX 1024
/* Threads whose last failure a context remembers at once (the least recent is forgotten). */
#define NC_ERROR_SLOTS 32

/* The last failure of one thread on a context. */
typedef struct nc_error_slot {
    pthread_t thread;
    bool used;
    uint64_t seq; /* when it was written, for forgetting the least recent */
    nacre_result result;
    char message[NC_ERROR_MAX];
} nc_error_slot;

struct nacre_context {
    nacre_allocator allocator;
    int threads;
    nacre_log_fn log_fn;
    void *log_user;
    pthread_mutex_t lock; /* guards the error slots when several threads fail at once */
    nc_error_slot errors[NC_ERROR_SLOTS];
    uint64_t error_seq;
    uint64_t scene_serial; /* identifies scenes for renderer caches (addresses get reused) */
    uint64_t memory_limit; /* resolved: never 0 */
    _Atomic uint64_t memory_used, memory_peak; /* bytes held through nc_alloc (headers included) */
    /* The last shadow map generation given (nc_shadow_render): atomic, renderers sharing the
     * context may render at once */
    _Atomic uint64_t shadow_serial;
};

/* Record a failure and return its code. printf-style message. */
nacre_result nc_fail(nacre_context *ctx, nacre_result code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
nacre_result nc_failv(nacre_context *ctx, nacre_result code, const char *fmt, va_list ap);
/* Warning through the log callback only (no error state). */
void nc_warn(nacre_context *ctx, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/* Allocation through the context's allocator. nc_alloc returns NULL on failure (and records
 * NACRE_ERROR_OUT_OF_MEMORY); sizes are checked for overflow. */
void *nc_alloc(nacre_context *ctx, size_t size);
void *nc_calloc(nacre_context *ctx, size_t count, size_t size);
void nc_free(nacre_context *ctx, void *ptr);
/* Grow or shrink: copies min(old_size, new_size) bytes. */
void *nc_realloc(nacre_context *ctx, void *ptr, size_t old_size, size_t new_size);
char *nc_strdup(nacre_context *ctx, const char *s);
/* Scratch that only grows: when `count` elements of `size` bytes exceed *capacity, the pointer
 * stored at `slot` (a `T **`, passed as void *) is freed and replaced by a new block of that
 * many, contents not kept. false (OUT_OF_MEMORY recorded) when the block cannot be had; the old
 * one stays. */
bool nc_reserve(nacre_context *ctx, void *slot, size_t *capacity, size_t count, size_t size);

/* An estimate made before a large allocation (or a set of them): fails with
 * NACRE_ERROR_OUT_OF_MEMORY, "<what> needs <size>, over the memory limit of <limit> ...", when
 * `bytes` more than what is held now would exceed the context's memory limit. `what` names the
 * thing and the setting that sized it ("voxel grid 4096^3 (voxel resolution)"). */
nacre_result nc_memory_check(nacre_context *ctx, uint64_t bytes, const char *what);
/* "12.5 MiB": a byte count for messages, into buf (at least 32 chars); returns buf. */
const char *nc_format_bytes(uint64_t bytes, char *buf, size_t size);

/* a * b without overflow; false if it would overflow. */
static inline bool nc_mul_size_ok(size_t a, size_t b, size_t *out)
{
    if (a != 0 && b > SIZE_MAX / a)
        return false;
    *out = a * b;
    return true;
}

/* What a row's new range [b0, b1) leaves of its old range [a0, a1): [r[0], r[1]) left of the new
 * range and [r[2], r[3]) right of it, either possibly empty (end <= start; an empty new range
 * leaves all of the old one). The passes that keep their last output and rewrite only what
 * changed (the shading pass's background, the solver's zeros, the exitance grid) clear these. */
static inline void nc_range_minus(int64_t a0, int64_t a1, int64_t b0, int64_t b1, int64_t r[4])
{
    r[0] = a0;
    r[1] = b0 < a1 ? b0 : a1;
    r[2] = b1 > a0 ? b1 : a0;
    r[3] = a1;
}

/* The first (last) nonzero byte of p[0, n), n if none: 8 bytes at a time on little-endian
 * machines. For the extent of a row of solid flags: the diffusion solver's bounding box and row
 * spans and the exitance pass scan every row of the grid, most of them empty (a byte at a time,
 * the bounding box alone took 0.6-1 ms per setup at 128^3). */
static inline size_t nc_first_nonzero(const uint8_t *p, size_t n)
{
    size_t i = 0;
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
    for (; i + 8 <= n; i += 8) {
        uint64_t w;
        memcpy(&w, p + i, 8);
        if (w)
            return i + (size_t)__builtin_ctzll(w) / 8;
    }
#endif
    for (; i < n; i++)
        if (p[i])
            return i;
    return n;
}

static inline size_t nc_last_nonzero(const uint8_t *p, size_t n)
{
    size_t i = n;
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
    for (; i >= 8; i -= 8) {
        uint64_t w;
        memcpy(&w, p + i - 8, 8);
        if (w)
            return i - 1 - (size_t)__builtin_clzll(w) / 8;
    }
#endif
    while (i > 0)
        if (p[--i])
            return i;
    return n;
}

/* Monotonic clock in microseconds. */
uint64_t nc_now_us(void);

/* Resolved OpenMP thread count for this context. */
static inline int nc_threads(const nacre_context *ctx) { return ctx->threads; }

#endif /* NACRE_CORE_H */
