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

/* The image readers choose their decoder by extension: PNG by its signature, anything else is
 * given to the EXR reader (whose magic the mutations may just as well break). */
static inline const char *fuzz_image_extension(const uint8_t *data, size_t size)
{
    return fuzz_starts_with(data, size, "\x89PNG", 4) ? "png" : "exr";
}

/* Known problem, not yet fixed in the library (issue 29): the image readers allocate what the
 * header declares (up to 2^28 pixels, 4 GB of floats) before any pixel data is read, so a 34-byte
 * PNG or EXR asks for gigabytes and libFuzzer stops at its malloc limit. Until the readers bound the
 * size by what the file can hold, inputs declaring more than FUZZ_MAX_PIXELS are skipped (the
 * header fields are read here the way the decoders read them). NACRE_FUZZ_NO_GUARDS=1 turns the
 * skip off, to check a fix. */
#define FUZZ_MAX_PIXELS ((uint64_t)1 << 22)

static inline bool fuzz_guards_on(void)
{
    static int on = -1;
    if (on < 0) {
        const char *v = getenv("NACRE_FUZZ_NO_GUARDS");
        on = !(v && *v && strcmp(v, "0") != 0);
    }
    return on != 0;
}

static inline uint32_t fuzz_be32(const uint8_t *p)
{
    return (uint32_t)p[0] << 24 | (uint32_t)p[1] << 16 | (uint32_t)p[2] << 8 | p[3];
}

/* w * h > FUZZ_MAX_PIXELS without overflowing (w, h up to 2^32). */
static inline bool fuzz_pixels_over(uint64_t w, uint64_t h)
{
    return w > 0 && h > 0 && w > FUZZ_MAX_PIXELS / h;
}

static inline int32_t fuzz_le32(const uint8_t *p)
{
    return (int32_t)((uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24);
}

/* Whether a PNG's IHDR or any EXR "dataWindow" attribute (every part of a multi-part file)
 * declares more than FUZZ_MAX_PIXELS. */
static inline bool fuzz_image_too_big(const uint8_t *data, size_t size)
{
    if (!fuzz_guards_on())
        return false;
    if (fuzz_starts_with(data, size, "\x89PNG", 4))
        return size >= 24 && fuzz_pixels_over(fuzz_be32(data + 16), fuzz_be32(data + 20));
    static const char name[] = "dataWindow";
    const size_t n = sizeof(name); /* with its NUL */
    for (size_t i = 0; i + n <= size; i++) {
        if (memcmp(data + i, name, n) != 0)
            continue;
        size_t at = i + n;
        while (at < size && data[at] != 0) /* the type name ("box2i") */
            at++;
        at += 1 + 4; /* its NUL and the attribute size */
        if (at + 16 > size)
            break;
        int64_t w = (int64_t)fuzz_le32(data + at + 8) - fuzz_le32(data + at) + 1;
        int64_t h = (int64_t)fuzz_le32(data + at + 12) - fuzz_le32(data + at + 4) + 1;
        if (w > 0 && h > 0 && fuzz_pixels_over((uint64_t)w, (uint64_t)h))
            return true;
    }
    return false;
}

#endif /* NACRE_FUZZ_COMMON_H */
