/*
 * tmpfile.c: see tmpfile.h. mkstemp in the destination's folder (so the rename stays on one
 * file system and is atomic), write, close (which can report a delayed write error), rename.
 */
#include "io/tmpfile.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

nacre_result nc_tmpfile_open(nacre_context *ctx, const char *path, nc_tmpfile *tmp)
{
    static const char suffix[] = ".tmpXXXXXX";
    tmp->path = path;
    tmp->fd = -1;
    size_t n = strlen(path);
    tmp->tmp_path = nc_alloc(ctx, n + sizeof(suffix));
    if (!tmp->tmp_path)
        return NACRE_ERROR_OUT_OF_MEMORY;
    memcpy(tmp->tmp_path, path, n);
    memcpy(tmp->tmp_path + n, suffix, sizeof(suffix));
    tmp->fd = mkstemp(tmp->tmp_path);
    if (tmp->fd < 0) {
        int err = errno;
        nc_free(ctx, tmp->tmp_path);
        tmp->tmp_path = NULL;
        return nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot create file: %s", path, strerror(err));
    }
    /* mkstemp makes the file 0600; an output is an ordinary document, readable by others. */
    (void)fchmod(tmp->fd, 0644);
    return NACRE_OK;
}

nacre_result nc_tmpfile_write(nacre_context *ctx, nc_tmpfile *tmp, const void *data, size_t size)
{
    const unsigned char *p = data;
    while (size > 0) {
        ssize_t k = write(tmp->fd, p, size);
        if (k < 0) {
            if (errno == EINTR)
                continue;
            return nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot write file: %s", tmp->path,
                           strerror(errno));
        }
        p += k;
        size -= (size_t)k;
    }
    return NACRE_OK;
}

static void tmpfile_release(nacre_context *ctx, nc_tmpfile *tmp)
{
    nc_free(ctx, tmp->tmp_path);
    tmp->tmp_path = NULL;
    tmp->fd = -1;
}

nacre_result nc_tmpfile_commit(nacre_context *ctx, nc_tmpfile *tmp)
{
    nacre_result r = NACRE_OK;
    /* close() can report a delayed write error (NFS, full disk): the file is not good then. */
    if (close(tmp->fd) != 0)
        r = nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot write file: %s", tmp->path,
                    strerror(errno));
    else if (rename(tmp->tmp_path, tmp->path) != 0)
        r = nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot rename temporary file into place: %s",
                    tmp->path, strerror(errno));
    if (r != NACRE_OK)
        unlink(tmp->tmp_path);
    tmpfile_release(ctx, tmp);
    return r;
}

void nc_tmpfile_abort(nacre_context *ctx, nc_tmpfile *tmp)
{
    if (!tmp->tmp_path)
        return;
    if (tmp->fd >= 0)
        close(tmp->fd);
    unlink(tmp->tmp_path);
    tmpfile_release(ctx, tmp);
}

nacre_result nc_read_file(nacre_context *ctx, const char *path, size_t max_bytes, const char *too_big, char **out,
                          size_t *size)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        int e = errno;
        char reason[128];
        if (strerror_r(e, reason, sizeof(reason)) != 0)
            snprintf(reason, sizeof(reason), "error %d", e);
        return nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot open: %s", path, reason);
    }
    size_t cap = 0, len = 0;
    char *buf = NULL;
    nacre_result r = NACRE_OK;
    for (;;) {
        if (len == cap) {
            size_t grown = cap ? cap * 2 : 16384;
            if (cap >= max_bytes) {
                r = nc_fail(ctx, NACRE_ERROR_IO, "%s: larger than %zu MiB, %s", path, max_bytes >> 20, too_big);
                break;
            }
            char *p = nc_realloc(ctx, buf, len, grown);
            if (!p) {
                r = NACRE_ERROR_OUT_OF_MEMORY;
                break;
            }
            buf = p;
            cap = grown;
        }
        size_t n = fread(buf + len, 1, cap - len, f);
        len += n;
        if (n == 0) {
            if (ferror(f)) {
                int e = errno;
                char reason[128];
                if (strerror_r(e, reason, sizeof(reason)) != 0)
                    snprintf(reason, sizeof(reason), "error %d", e);
                r = nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot read: %s", path, reason);
            }
            break;
        }
    }
    fclose(f);
    if (r != NACRE_OK) {
        nc_free(ctx, buf);
        return r;
    }
    *out = buf;
    *size = len;
    return NACRE_OK;
}
