/*
 * core.h: the base of nacre's public C API: the NACRE_API export macro, the version, the result
 * codes (NACRE_RESULT_LIST, nacre_result), and the context (allocator, threads, log callback,
 * memory limit, last error) with nacre_free. Every other public header includes it. The
 * conventions (units, ownership, memory, threading, errors) are in the opening comment of nacre.h.
 */
#ifndef NACRE_PUBLIC_CORE_H
#define NACRE_PUBLIC_CORE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#if defined(NACRE_BUILDING) && defined(__GNUC__)
#define NACRE_API __attribute__((visibility("default")))
#else
#define NACRE_API
#endif

/* ------------------------------------------------------------------------------------------ */
/* Version, results                                                                          */
/* ------------------------------------------------------------------------------------------ */

#define NACRE_VERSION_MAJOR 0
#define NACRE_VERSION_MINOR 1
#define NACRE_VERSION_PATCH 0

/* Result codes and their names come from this one list. */
#define NACRE_RESULT_LIST(X)                                                                   \
    X(NACRE_OK, 0, "ok")                                                                       \
    X(NACRE_ERROR_INVALID_ARGUMENT, 1, "invalid argument")                                     \
    X(NACRE_ERROR_IO, 2, "input/output error")                                                 \
    X(NACRE_ERROR_PARSE, 3, "parse error")                                                     \
    X(NACRE_ERROR_OUT_OF_MEMORY, 4, "out of memory")                                           \
    X(NACRE_ERROR_UNSUPPORTED, 5, "not supported")                                             \
    X(NACRE_ERROR_CANCELLED, 6, "cancelled")                                                   \
    X(NACRE_ERROR_INVALID_OPERATION, 7, "invalid operation")

typedef enum nacre_result {
#define NACRE_RESULT_ENUM_(name, value, text) name = value,
    NACRE_RESULT_LIST(NACRE_RESULT_ENUM_)
#undef NACRE_RESULT_ENUM_
} nacre_result;

/* Version string "MAJOR.MINOR.PATCH". */
NACRE_API const char *nacre_version(void);
/* Short English name of a result code ("parse error"). */
NACRE_API const char *nacre_result_string(nacre_result result);

/* ------------------------------------------------------------------------------------------ */
/* Context: allocator, threads, error messages                                               */
/* ------------------------------------------------------------------------------------------ */

typedef struct nacre_context nacre_context;

typedef enum nacre_log_level { NACRE_LOG_ERROR = 0, NACRE_LOG_WARNING, NACRE_LOG_INFO } nacre_log_level;

/* Reentrant: may be called from several threads at once. */
typedef void (*nacre_log_fn)(void *user, nacre_log_level level, const char *message);

typedef struct nacre_allocator {
    void *(*alloc_fn)(size_t size, void *user); /* NULL with free_fn NULL: malloc */
    void (*free_fn)(void *ptr, void *user);     /* must accept NULL */
    void *user;
} nacre_allocator;

typedef struct nacre_context_desc {
    nacre_allocator allocator; /* zero: malloc/free */
    int threads;               /* 0: all hardware threads; 1: serial (debugging) */
    nacre_log_fn log_fn;       /* optional */
    void *log_user;
    /* Bytes the library may hold at once through this context (images, meshes, voxel grids,
     * shadow maps, solver arrays, volumes). 0: half of physical memory, or less when the
     * process's address space is limited (RLIMIT_AS, `ulimit -v`). An allocation or an estimate
     * made before a large allocation that would go over it fails with NACRE_ERROR_OUT_OF_MEMORY
     * and a message naming the size needed and this limit. */
    uint64_t memory_limit;
} nacre_context_desc;

/* Create a context. desc may be NULL (defaults). */
NACRE_API nacre_result nacre_context_create(const nacre_context_desc *desc, nacre_context **out);
/* Destroy a context; every scene and renderer made from it must be destroyed first. */
NACRE_API void nacre_context_destroy(nacre_context *ctx);
/* Message of the calling thread's latest failure on this context ("" if none): a failure on
 * another thread (another renderer sharing the context) does not replace it. Valid until this
 * thread's next failure on the context; the context remembers the last failure of the 32 threads
 * that failed most recently. */
NACRE_API const char *nacre_context_last_error(const nacre_context *ctx);
/* Result code of the calling thread's latest failure on this context (NACRE_OK if none). */
NACRE_API nacre_result nacre_context_last_result(const nacre_context *ctx);
/* Forget the calling thread's latest failure. */
NACRE_API void nacre_context_clear_error(nacre_context *ctx);
/* Number of threads renders use (resolved from the desc). */
NACRE_API int nacre_context_threads(const nacre_context *ctx);
/* Free one array the library allocated through this context (e.g. normals it computed into a
 * mesh the caller built). NULL does nothing. */
NACRE_API void nacre_free(nacre_context *ctx, void *ptr);
/* The memory limit in bytes (resolved from the desc), and a new one (0: the default again).
 * Lowering it below what is in use fails later allocations only; nothing is freed. */
NACRE_API uint64_t nacre_context_memory_limit(const nacre_context *ctx);
NACRE_API nacre_result nacre_context_set_memory_limit(nacre_context *ctx, uint64_t bytes);
/* Bytes held now through this context, and the most held at once since its creation. */
NACRE_API uint64_t nacre_context_memory_used(const nacre_context *ctx);
NACRE_API uint64_t nacre_context_memory_peak(const nacre_context *ctx);

#ifdef __cplusplus
}
#endif

#endif /* NACRE_PUBLIC_CORE_H */
