/*
 * fuzz_common.h: what the libFuzzer targets of this folder share (header-only, one target per
 * executable): a serial context per input, a per-process temporary file for the loaders that
 * only take a path, format sniffing for those that choose the decoder by extension, the leak
 * suppression for assimp and the checks every failure must pass.
 *
 * A broken invariant calls FUZZ_REQUIRE, which prints the condition and aborts: libFuzzer then
 * reports the input as a crash and saves it, as it does for a sanitizer report.
 */
#ifndef NACRE_FUZZ_COMMON_H
#define NACRE_FUZZ_COMMON_H

#include <nacre/nacre.h>

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* assimp 5.2 leaks the meshes it has built when its parsers throw on a bad file; nothing nacre
 * can free (the rule of tests/lsan.supp). In the source rather than in LSAN_OPTIONS so that a
 * target run by hand on a saved crash reports the same leaks as the bounded run. */
const char *__lsan_default_suppressions(void);
const char *__lsan_default_suppressions(void) { return "leak:libassimp.so\n"; }

#define FUZZ_REQUIRE(cond)                                                                     \
    do {                                                                                       \
        if (!(cond)) {                                                                         \
            fprintf(stderr, "%s:%d: FUZZ_REQUIRE(%s) failed\n", __FILE__, __LINE__, #cond);    \
            abort();                                                                           \
        }                                                                                      \
    } while (0)

/* One thread: an input's behaviour does not depend on the machine, and OpenMP starts no team
 * for every input. A fresh context per input keeps no state from one input to the next. */
static inline nacre_context *fuzz_context(void)
{
    nacre_context_desc desc = {0};
    desc.threads = 1;
    nacre_context *ctx = NULL;
    FUZZ_REQUIRE(nacre_context_create(&desc, &ctx) == NACRE_OK && ctx);
    return ctx;
}

/* A failure must say why on one non-empty line (the API's promise). NACRE_FUZZ_VERBOSE=1 prints
 * it: to see why a seed is refused, or what a saved input does. */
static inline void fuzz_check_failure(const nacre_context *ctx, nacre_result r)
{
    FUZZ_REQUIRE(r != NACRE_OK);
    FUZZ_REQUIRE(nacre_context_last_result(ctx) == r);
    const char *msg = nacre_context_last_error(ctx);
    FUZZ_REQUIRE(msg && msg[0] != '\0' && !strchr(msg, '\n'));
    static int verbose = -1;
    if (verbose < 0) {
        const char *v = getenv("NACRE_FUZZ_VERBOSE");
        verbose = v && *v && strcmp(v, "0") != 0;
    }
    if (verbose)
        fprintf(stderr, "fuzz: %s: %s\n", nacre_result_string(r), msg);
}

/* <dir>/nacre-fuzz-<tag>-<pid>.<ext>, dir from NACRE_FUZZ_TMP, TMPDIR or /tmp. The pid keeps
 * parallel fuzzing processes (-jobs, -fork) apart. */
static inline void fuzz_temp_path(char *out, size_t cap, const char *tag, const char *ext)
{
    const char *dir = getenv("NACRE_FUZZ_TMP");
    if (!dir || !*dir)
        dir = getenv("TMPDIR");
    if (!dir || !*dir)
        dir = "/tmp";
    int n = snprintf(out, cap, "%s/nacre-fuzz-%s-%ld.%s", dir, tag, (long)getpid(), ext);
    FUZZ_REQUIRE(n > 0 && (size_t)n < cap);
}

static inline void fuzz_write_file(const char *path, const uint8_t *data, size_t size)
{
    FILE *f = fopen(path, "wb");
    if (!f) {
        fprintf(stderr, "fuzz: cannot write %s (set NACRE_FUZZ_TMP to a writable folder)\n", path);
        abort();
    }
    FUZZ_REQUIRE(size == 0 || fwrite(data, 1, size, f) == size);
    FUZZ_REQUIRE(fclose(f) == 0);
}

static inline bool fuzz_starts_with(const uint8_t *data, size_t size, const char *magic, size_t n)
{
    return size >= n && memcmp(data, magic, n) == 0;
}

/* The image readers choose their decoder by extension: PNG and JPEG by their signatures, anything
 * else is given to the EXR reader (whose magic the mutations may just as well break). */
static inline const char *fuzz_image_extension(const uint8_t *data, size_t size)
{
    if (fuzz_starts_with(data, size, "\x89PNG", 4))
        return "png";
    return fuzz_starts_with(data, size, "\xFF\xD8\xFF", 3) ? "jpg" : "exr";
}


#endif /* NACRE_FUZZ_COMMON_H */
