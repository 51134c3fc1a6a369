/*
 * tmpfile.h: whole files in and out. Writing goes under a temporary name next to its final path
 * and is renamed into place once complete, so that a failed or interrupted write never leaves a
 * partial file at the path (images, NRRD volumes); reading takes a whole file into memory (scene
 * files, JPEG images). Private to the library.
 */
#ifndef NACRE_TMPFILE_H
#define NACRE_TMPFILE_H

#include "core/core.h"

/* A file being written under a temporary name next to its final path. */
typedef struct nc_tmpfile {
    const char *path; /* final path (borrowed) */
    char *tmp_path;   /* path + ".tmpXXXXXX", allocated */
    int fd;           /* -1 once closed */
} nc_tmpfile;

/* Create the temporary file in the folder of `path`. */
nacre_result nc_tmpfile_open(nacre_context *ctx, const char *path, nc_tmpfile *tmp);
/* Write all of `data` at the current position; errno-style message on failure. */
nacre_result nc_tmpfile_write(nacre_context *ctx, nc_tmpfile *tmp, const void *data, size_t size);
/* Close and rename into place. On failure the temporary file is removed. Always releases tmp. */
nacre_result nc_tmpfile_commit(nacre_context *ctx, nc_tmpfile *tmp);
/* Close and remove the temporary file (after a failed write). Always releases tmp. */
void nc_tmpfile_abort(nacre_context *ctx, nc_tmpfile *tmp);

/* The whole file at `path` in *out (allocated through ctx, *size bytes; reads pipes too). Files of
 * max_bytes or more fail with "PATH: larger than N MiB, <too_big>". */
nacre_result nc_read_file(nacre_context *ctx, const char *path, size_t max_bytes, const char *too_big, char **out,
                          size_t *size);

#endif /* NACRE_TMPFILE_H */
