/*
 * script.h: the timed events of `nacre view --script FILE`, for tests and scripted runs. One
 * event per line, "FRAME COMMAND ARGS...", applied before frame FRAME (0-based) renders; the
 * grammar is in script.c and `nacre view --help`. A script is checked whole against the scene
 * before the window opens, so a bad line ends the run with one message naming it.
 */
#ifndef NACRE_VIEW_SCRIPT_H
#define NACRE_VIEW_SCRIPT_H

#include "view.h"

#define NC_SCRIPT_MAX_ARGS 8

typedef struct nc_script_event {
    long frame;
    int line;
    int argc;                          /* command and its arguments */
    char *argv[NC_SCRIPT_MAX_ARGS];    /* point into `text` */
} nc_script_event;

typedef struct nc_script {
    char *path;
    char *text;                        /* the file, split into tokens in place */
    nc_script_event *events;           /* sorted by frame, file order within a frame */
    size_t count;
    size_t next;                       /* first event not yet applied */
} nc_script;

/* Read and tokenize; false with "FILE:LINE: problem" in err. */
bool nc_script_load(const char *path, nc_script *s, char *err, size_t err_size);
/* Check every event against the view (indices, names, values) and that none is at or past
 * `frames` (0: no limit); false with "FILE:LINE: problem" in err. Changes nothing. */
bool nc_script_check(nc_script *s, nc_view *v, long frames, char *err, size_t err_size);
/* Apply the events of frame `frame`; false with the message in err if one is refused. */
bool nc_script_run(nc_script *s, nc_view *v, long frame, char *err, size_t err_size);
void nc_script_free(nc_script *s);

#endif /* NACRE_VIEW_SCRIPT_H */
