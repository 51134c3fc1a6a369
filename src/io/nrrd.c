/*
 * nrrd.c: a small reader and writer for NRRD volumes (Teem's "Nearly Raw Raster Data", format versions
 * NRRD0001-0005), used for density volumes of heterogeneous materials (NACRE_PATTERN_VOLUME,
 * issue 4 item 5) and able to read the voxelizer's own exports (nacre_voxel_grid_write_nrrd).
 *
 * Supported: attached data with raw encoding; types int8/uint8/int16/uint16/int32/uint32/float/
 * double (with their NRRD aliases) in either byte order; dimension 3, or 4 whose first axis holds
 * channels (one is read); "space origin" with axis-aligned positive "space directions", or
 * "spacings"; "byte skip" (including -1) and "line skip". Not supported, with an error naming the
 * field: compressed or text encodings, detached data ("data file"), 64-bit integers, rotated or
 * flipped axes. Sample positions follow NRRD: "space origin" is the first sample's position.
 * Units are whatever the file's space uses; nacre takes them as rest-pose scene units.
 *
 * The input is untrusted (it is fuzzed): every size is checked before arithmetic or allocation,
 * lines are bounded, and every failure is one message "name: line N: field: problem" (or
 * "name: field: problem" for problems that are not on one line).
 */
#include "io/nrrd.h"
#include "io/tmpfile.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define LINE_MAX_CHARS 4096

typedef enum sample_type { T_NONE = 0, T_I8, T_U8, T_I16, T_U16, T_I32, T_U32, T_F32, T_F64 } sample_type;

static const struct {
    const char *name;
    sample_type type;
} type_names[] = {
    {"int8", T_I8}, {"int8_t", T_I8}, {"signed char", T_I8},
    {"uint8", T_U8}, {"uint8_t", T_U8}, {"uchar", T_U8}, {"unsigned char", T_U8},
    {"int16", T_I16}, {"int16_t", T_I16}, {"short", T_I16}, {"short int", T_I16},
    {"signed short", T_I16}, {"signed short int", T_I16},
    {"uint16", T_U16}, {"uint16_t", T_U16}, {"ushort", T_U16}, {"unsigned short", T_U16},
    {"unsigned short int", T_U16},
    {"int32", T_I32}, {"int32_t", T_I32}, {"int", T_I32}, {"signed int", T_I32},
    {"uint32", T_U32}, {"uint32_t", T_U32}, {"uint", T_U32}, {"unsigned int", T_U32},
    {"float", T_F32}, {"double", T_F64},
};

/* Fields that may appear and do not change how nacre reads the samples. */
static const char *const ignored_fields[] = {
    "content", "min", "max", "old min", "oldmin", "old max", "oldmax", "labels", "units",
    "space units", "measurement frame", "axis mins", "axismins", "axis maxs", "axismaxs",
    "thicknesses", "sample units", "sampleunits", "number", "kinds", "centers", "centerings",
    "space",
};

static size_t type_size(sample_type t)
{
    switch (t) {
    case T_I8: case T_U8: return 1;
    case T_I16: case T_U16: return 2;
    case T_I32: case T_U32: case T_F32: return 4;
    case T_F64: return 8;
    case T_NONE: break;
    }
    return 0;
}

typedef struct header {
    uint32_t dimension;       /* 0: not given yet */
    uint64_t sizes[4];
    bool have_sizes, have_encoding, have_space_dim, have_dirs, have_origin, have_spacings;
    bool have_byte_skip, have_line_skip;
    sample_type type;
    int endian;               /* 0: not given, 1: little, 2: big */
    bool dir_none[4];
    double dirs[4][3];
    double origin[3];
    double spacings[4];
    int64_t byte_skip;        /* -1: data ends the file */
    uint64_t line_skip;
} header;

/* Parser state for messages. */
typedef struct parser {
    nacre_context *ctx;
    const char *name;
    unsigned line;
} parser;

static nacre_result line_error(const parser *ps, const char *field, const char *problem)
{
    return nc_fail(ps->ctx, NACRE_ERROR_PARSE, "%s: line %u: %s: %s", ps->name, ps->line, field, problem);
}

/* ------------------------------------------------------------------------------------------ */
/* Value parsing (on one NUL-terminated line copy)                                            */
/* ------------------------------------------------------------------------------------------ */

static void skip_ws(const char **s)
{
    while (**s == ' ' || **s == '\t')
        (*s)++;
}

static bool at_end(const char *s)
{
    skip_ws(&s);
    return *s == '\0';
}

/* Unsigned decimal integer, no sign, no overflow past `max`. */
static bool parse_uint(const char **s, uint64_t max, uint64_t *out)
{
    skip_ws(s);
    const char *p = *s;
    uint64_t v = 0;
    if (*p < '0' || *p > '9')
        return false;
    for (; *p >= '0' && *p <= '9'; p++) {
        uint64_t d = (uint64_t)(*p - '0');
        if (v > (max - d) / 10)
            return false;
        v = v * 10 + d;
    }
    *s = p;
    *out = v;
    return true;
}

static bool parse_double(const char **s, double *out)
{
    skip_ws(s);
    char *end = NULL;
    errno = 0;
    double v = strtod(*s, &end);
    if (end == *s)
        return false;
    *s = end;
    *out = v;
    return true;
}

/* "(a,b,c)" with optional blanks; all components finite. */
static bool parse_vector3(const char **s, double v[3])
{
    skip_ws(s);
    if (**s != '(')
        return false;
    (*s)++;
    for (int k = 0; k < 3; k++) {
        if (!parse_double(s, &v[k]) || !isfinite(v[k]))
            return false;
        skip_ws(s);
        if (**s != (k < 2 ? ',' : ')'))
            return false;
        (*s)++;
    }
    return true;
}

/* ------------------------------------------------------------------------------------------ */
/* Header fields                                                                              */
/* ------------------------------------------------------------------------------------------ */

static nacre_result need_dimension(const parser *ps, const header *h, const char *field)
{
    return h->dimension ? NACRE_OK : line_error(ps, field, "must come after 'dimension'");
}

static nacre_result parse_field(const parser *ps, header *h, const char *key, const char *v)
{
    char word[64];
    if (strcmp(key, "type") == 0) {
        if (h->type != T_NONE)
            return line_error(ps, key, "given twice");
        skip_ws(&v);
        size_t n = strlen(v);
        while (n > 0 && (v[n - 1] == ' ' || v[n - 1] == '\t'))
            n--;
        for (size_t i = 0; i < sizeof(type_names) / sizeof(type_names[0]); i++)
            if (strlen(type_names[i].name) == n && strncmp(type_names[i].name, v, n) == 0)
                h->type = type_names[i].type;
        if (h->type == T_NONE)
            return line_error(ps, key, "unsupported (int8, uint8, int16, uint16, int32, uint32, float, double)");
        return NACRE_OK;
    }
    if (strcmp(key, "dimension") == 0) {
        uint64_t d = 0;
        if (h->dimension)
            return line_error(ps, key, "given twice");
        if (!parse_uint(&v, 1000, &d) || !at_end(v))
            return line_error(ps, key, "expected a positive integer");
        if (d != 3 && d != 4)
            return line_error(ps, key, "must be 3, or 4 with a leading channel axis");
        h->dimension = (uint32_t)d;
        return NACRE_OK;
    }
    if (strcmp(key, "sizes") == 0) {
        nacre_result r = need_dimension(ps, h, key);
        if (r != NACRE_OK)
            return r;
        if (h->have_sizes)
            return line_error(ps, key, "given twice");
        for (uint32_t a = 0; a < h->dimension; a++)
            if (!parse_uint(&v, NC_NRRD_SAMPLES_MAX, &h->sizes[a]) || h->sizes[a] == 0)
                return line_error(ps, key, "expected one positive integer (at most 2^31) per axis");
        if (!at_end(v))
            return line_error(ps, key, "more values than 'dimension'");
        h->have_sizes = true;
        return NACRE_OK;
    }
    if (strcmp(key, "encoding") == 0) {
        if (h->have_encoding)
            return line_error(ps, key, "given twice");
        skip_ws(&v);
        if (sscanf(v, "%63s", word) != 1 || strcmp(word, "raw") != 0 || !at_end(v + strlen(word)))
            return line_error(ps, key, "only 'raw' is supported");
        h->have_encoding = true;
        return NACRE_OK;
    }
    if (strcmp(key, "endian") == 0) {
        if (h->endian)
            return line_error(ps, key, "given twice");
        skip_ws(&v);
        if (strncmp(v, "little", 6) == 0 && at_end(v + 6))
            h->endian = 1;
        else if (strncmp(v, "big", 3) == 0 && at_end(v + 3))
            h->endian = 2;
        else
            return line_error(ps, key, "must be 'little' or 'big'");
        return NACRE_OK;
    }
    if (strcmp(key, "space dimension") == 0) {
        uint64_t d = 0;
        if (h->have_space_dim)
            return line_error(ps, key, "given twice");
        if (!parse_uint(&v, 1000, &d) || !at_end(v) || d != 3)
            return line_error(ps, key, "must be 3");
        h->have_space_dim = true;
        return NACRE_OK;
    }
    if (strcmp(key, "space directions") == 0) {
        nacre_result r = need_dimension(ps, h, key);
        if (r != NACRE_OK)
            return r;
        if (h->have_dirs)
            return line_error(ps, key, "given twice");
        if (!h->have_space_dim)
            return line_error(ps, key, "needs 'space dimension' or 'space' first");
        for (uint32_t a = 0; a < h->dimension; a++) {
            skip_ws(&v);
            if (strncmp(v, "none", 4) == 0) {
                h->dir_none[a] = true;
                v += 4;
            } else if (!parse_vector3(&v, h->dirs[a])) {
                return line_error(ps, key, "expected one '(x,y,z)' or 'none' per axis");
            }
        }
        if (!at_end(v))
            return line_error(ps, key, "more vectors than 'dimension'");
        h->have_dirs = true;
        return NACRE_OK;
    }
    if (strcmp(key, "space origin") == 0) {
        if (h->have_origin)
            return line_error(ps, key, "given twice");
        if (!h->have_space_dim)
            return line_error(ps, key, "needs 'space dimension' or 'space' first");
        if (!parse_vector3(&v, h->origin) || !at_end(v))
            return line_error(ps, key, "expected '(x,y,z)' with finite numbers");
        h->have_origin = true;
        return NACRE_OK;
    }
    if (strcmp(key, "spacings") == 0) {
        nacre_result r = need_dimension(ps, h, key);
        if (r != NACRE_OK)
            return r;
        if (h->have_spacings)
            return line_error(ps, key, "given twice");
        for (uint32_t a = 0; a < h->dimension; a++)
            if (!parse_double(&v, &h->spacings[a]))
                return line_error(ps, key, "expected one number (or nan) per axis");
        if (!at_end(v))
            return line_error(ps, key, "more values than 'dimension'");
        h->have_spacings = true;
        return NACRE_OK;
    }
    if (strcmp(key, "byte skip") == 0 || strcmp(key, "byteskip") == 0) {
        if (h->have_byte_skip)
            return line_error(ps, key, "given twice");
        skip_ws(&v);
        uint64_t b = 0;
        if (strncmp(v, "-1", 2) == 0 && at_end(v + 2))
            h->byte_skip = -1;
        else if (parse_uint(&v, (uint64_t)1 << 40, &b) && at_end(v))
            h->byte_skip = (int64_t)b;
        else
            return line_error(ps, key, "expected -1 or a non-negative integer");
        h->have_byte_skip = true;
        return NACRE_OK;
    }
    if (strcmp(key, "line skip") == 0 || strcmp(key, "lineskip") == 0) {
        if (h->have_line_skip)
            return line_error(ps, key, "given twice");
        if (!parse_uint(&v, (uint64_t)1 << 32, &h->line_skip) || !at_end(v))
            return line_error(ps, key, "expected a non-negative integer");
        h->have_line_skip = true;
        return NACRE_OK;
    }
    if (strcmp(key, "data file") == 0 || strcmp(key, "datafile") == 0)
        return line_error(ps, key, "detached data is not supported (attach the data to the header)");
    if (strcmp(key, "block size") == 0 || strcmp(key, "blocksize") == 0)
        return line_error(ps, key, "block type is not supported");
    for (size_t i = 0; i < sizeof(ignored_fields) / sizeof(ignored_fields[0]); i++)
        if (strcmp(key, ignored_fields[i]) == 0) {
            /* "space" names an orientation (RAS, LPS, ...) and implies 3 space dimensions. */
            if (strcmp(key, "space") == 0) {
                if (h->have_space_dim)
                    return line_error(ps, key, "given twice (or with 'space dimension')");
                h->have_space_dim = true;
            }
            return NACRE_OK;
        }
    return line_error(ps, key, "unknown field");
}

/* ------------------------------------------------------------------------------------------ */
/* Samples                                                                                    */
/* ------------------------------------------------------------------------------------------ */

static double read_sample(const uint8_t *p, sample_type t, bool big)
{
    size_t n = type_size(t);
    uint8_t b[8] = {0};
    for (size_t i = 0; i < n; i++)
        b[i] = big ? p[n - 1 - i] : p[i];
    uint64_t u = 0;
    for (size_t i = 0; i < n; i++)
        u |= (uint64_t)b[i] << (8 * i);
    switch (t) {
    case T_I8: return (double)(int8_t)(uint8_t)u;
    case T_U8: return (double)(uint8_t)u;
    case T_I16: return (double)(int16_t)(uint16_t)u;
    case T_U16: return (double)(uint16_t)u;
    case T_I32: return (double)(int32_t)(uint32_t)u;
    case T_U32: return (double)(uint32_t)u;
    case T_F32: {
        uint32_t w = (uint32_t)u;
        float f;
        memcpy(&f, &w, sizeof(f));
        return (double)f;
    }
    case T_F64: {
        double d;
        memcpy(&d, &u, sizeof(d));
        return d;
    }
    case T_NONE: break;
    }
    return 0.0;
}

/* Placement of the spatial axes: spacing from "space directions" (axis-aligned, positive) or
 * "spacings", origin from "space origin"; defaults spacing 1, origin 0. */
static nacre_result placement(const parser *ps, const header *h, nacre_volume_data *out)
{
    uint32_t first = h->dimension - 3;
    if (h->have_dirs && h->have_spacings)
        return nc_fail(ps->ctx, NACRE_ERROR_PARSE, "%s: spacings: not allowed with 'space directions'", ps->name);
    if (first == 1 && h->have_dirs && !h->dir_none[0])
        return nc_fail(ps->ctx, NACRE_ERROR_PARSE,
                       "%s: space directions: the channel axis (the first) must be 'none'", ps->name);
    for (uint32_t k = 0; k < 3; k++) {
        uint32_t a = first + k;
        double s = 1.0;
        if (h->have_dirs) {
            if (h->dir_none[a])
                return nc_fail(ps->ctx, NACRE_ERROR_PARSE,
                               "%s: space directions: spatial axis %u is 'none'", ps->name, a);
            for (uint32_t j = 0; j < 3; j++)
                if (j != k && h->dirs[a][j] != 0.0)
                    return nc_fail(ps->ctx, NACRE_ERROR_UNSUPPORTED,
                                   "%s: space directions: axis %u is not aligned with space axis %u "
                                   "(rotated or permuted volumes are not supported)",
                                   ps->name, a, k);
            s = h->dirs[a][k];
        } else if (h->have_spacings) {
            s = h->spacings[a];
        }
        out->spacing[k] = (float)s;
        if (!(isfinite(out->spacing[k]) && out->spacing[k] > 0))
            return nc_fail(ps->ctx, NACRE_ERROR_UNSUPPORTED, "%s: %s: axis %u: spacing must be finite and > 0 (got %g)",
                           ps->name, h->have_dirs ? "space directions" : "spacings", a, s);
        out->origin[k] = h->have_origin ? (float)h->origin[k] : 0.0f;
        if (!isfinite(out->origin[k]))
            return nc_fail(ps->ctx, NACRE_ERROR_PARSE, "%s: space origin: out of float range", ps->name);
        out->dims[k] = (uint32_t)h->sizes[a];
    }
    return NACRE_OK;
}

nacre_result nc_nrrd_parse(nacre_context *ctx, const char *name, const uint8_t *bytes, size_t length,
                           uint32_t channel, nacre_volume_data *out)
{
    if (!ctx || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    memset(out, 0, sizeof(*out));
    if (!name)
        name = "nrrd";
    if (!bytes && length)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: no data", name);
    parser ps = {ctx, name, 0};
    header h;
    memset(&h, 0, sizeof(h));
    char line[LINE_MAX_CHARS + 1];
    size_t pos = 0;
    bool blank_seen = false;
    while (pos < length) {
        const uint8_t *nl = memchr(bytes + pos, '\n', length - pos);
        size_t end = nl ? (size_t)(nl - bytes) : length;
        size_t len = end - pos;
        ps.line++;
        if (len > 0 && bytes[pos + len - 1] == '\r')
            len--;
        if (len > LINE_MAX_CHARS)
            return line_error(&ps, "header", "line too long");
        if (memchr(bytes + pos, '\0', len))
            return line_error(&ps, "header", "NUL byte in the header");
        memcpy(line, bytes + pos, len);
        line[len] = '\0';
        pos = nl ? end + 1 : length;
        if (ps.line == 1) {
            if (!(len == 8 && strncmp(line, "NRRD000", 7) == 0 && line[7] >= '1' && line[7] <= '5'))
                return line_error(&ps, "magic", "not a NRRD file (expected NRRD0001..NRRD0005)");
            continue;
        }
        if (len == 0) {
            /* Without a trailing newline the blank line is not there: the data must follow it. */
            blank_seen = nl != NULL;
            break;
        }
        if (line[0] == '#')
            continue;
        char *sep = strstr(line, ": ");
        char *kv = strstr(line, ":=");
        if (kv && (!sep || kv < sep))
            continue; /* key/value pairs carry metadata nacre does not use */
        if (!sep) {
            if (line[len - 1] == ':') /* "field:" with an empty value */
                return line_error(&ps, "header", "field without a value");
            return line_error(&ps, "header", "expected 'field: value'");
        }
        *sep = '\0';
        nacre_result r = parse_field(&ps, &h, line, sep + 2);
        if (r != NACRE_OK)
            return r;
    }
    if (ps.line == 0)
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: empty file", name);
    if (!blank_seen)
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: header: no blank line before the data", name);
    if (h.type == T_NONE)
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: type: missing", name);
    if (!h.dimension)
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: dimension: missing", name);
    if (!h.have_sizes)
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: sizes: missing", name);
    if (!h.have_encoding)
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: encoding: missing", name);
    size_t tsize = type_size(h.type);
    if (tsize > 1 && !h.endian)
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: endian: missing (needed for types over one byte)", name);
    uint64_t channels = h.dimension == 4 ? h.sizes[0] : 1;
    if (channel >= channels)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: channel %u: the file has %llu channel(s)", name,
                       channel, (unsigned long long)channels);
    uint64_t total = 1;
    for (uint32_t a = 0; a < h.dimension; a++) {
        if (h.sizes[a] > NC_NRRD_SAMPLES_MAX / total)
            return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: sizes: more than 2^31 samples in all", name);
        total *= h.sizes[a];
    }
    nacre_result r = placement(&ps, &h, out);
    if (r != NACRE_OK) {
        memset(out, 0, sizeof(*out));
        return r;
    }
    /* total <= 2^31 and tsize <= 8: the byte count fits easily. */
    size_t need = (size_t)total * tsize;
    size_t start = pos;
    for (uint64_t i = 0; i < h.line_skip; i++) {
        const uint8_t *nl = start < length ? memchr(bytes + start, '\n', length - start) : NULL;
        if (!nl) {
            memset(out, 0, sizeof(*out));
            return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: line skip: file ends after %llu of %llu lines", name,
                           (unsigned long long)i, (unsigned long long)h.line_skip);
        }
        start = (size_t)(nl - bytes) + 1;
    }
    if (h.byte_skip == -1) {
        if (length - start < need) {
            memset(out, 0, sizeof(*out));
            return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: data: truncated (%zu of %zu bytes)", name, length - start, need);
        }
        start = length - need;
    } else if ((uint64_t)h.byte_skip > length - start) {
        memset(out, 0, sizeof(*out));
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: byte skip: past the end of the file", name);
    } else {
        start += (size_t)h.byte_skip;
    }
    if (length - start < need) {
        memset(out, 0, sizeof(*out));
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: data: truncated (%zu of %zu bytes)", name, length - start, need);
    }
    size_t n = (size_t)(total / channels);
    float *data = nc_alloc(ctx, n * sizeof(float));
    if (!data) {
        memset(out, 0, sizeof(*out));
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    const uint8_t *src = bytes + start;
    bool big = h.endian == 2;
    for (size_t i = 0; i < n; i++) {
        double v = read_sample(src + (i * (size_t)channels + channel) * tsize, h.type, big);
        float f = (float)v;
        if (!(isfinite(f) && f >= 0)) {
            nc_free(ctx, data);
            memset(out, 0, sizeof(*out));
            return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: data: sample %zu is %g (densities must be finite and >= 0)",
                           name, i, v);
        }
        data[i] = f;
    }
    out->data = data;
    return NACRE_OK;
}

nacre_result nacre_volume_load_nrrd(nacre_context *ctx, const char *path, uint32_t channel, nacre_volume_data *out)
{
    if (!ctx || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    memset(out, 0, sizeof(*out));
    if (!path)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "volume: no path");
    FILE *f = fopen(path, "rb");
    if (!f)
        return nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot open: %s", path, strerror(errno));
    nacre_result r = NACRE_OK;
    uint8_t *buf = NULL;
    long size = -1;
    if (fseek(f, 0, SEEK_END) == 0)
        size = ftell(f);
    if (size < 0 || fseek(f, 0, SEEK_SET) != 0) {
        r = nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot read (not a regular file?)", path);
        goto out;
    }
    if ((uint64_t)size > NC_NRRD_FILE_MAX) {
        r = nc_fail(ctx, NACRE_ERROR_IO, "%s: file too large (%ld bytes)", path, size);
        goto out;
    }
    buf = nc_alloc(ctx, (size_t)size + 1);
    if (!buf) {
        r = NACRE_ERROR_OUT_OF_MEMORY;
        goto out;
    }
    if (fread(buf, 1, (size_t)size, f) != (size_t)size) {
        r = nc_fail(ctx, NACRE_ERROR_IO, "%s: read failed", path);
        goto out;
    }
    r = nc_nrrd_parse(ctx, path, buf, (size_t)size, channel, out);
out:
    nc_free(ctx, buf);
    fclose(f);
    return r;
}

/* ------------------------------------------------------------------------------------------ */
/* Writing                                                                                    */
/* ------------------------------------------------------------------------------------------ */

nacre_result nc_nrrd_write_u8(nacre_context *ctx, const char *path, const char *comment, uint32_t channels,
                              const uint32_t dims[3], double spacing, const double origin[3], nc_nrrd_row_fn row_fn,
                              void *user)
{
    if (!path || channels == 0 || !row_fn)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "nrrd: no path, channel or row source");
    char header[1024];
    int n;
    if (channels > 1)
        n = snprintf(header, sizeof(header),
                     "NRRD0004\n# %s\ntype: uint8\ndimension: 4\nsizes: %u %u %u %u\n"
                     "kinds: vector domain domain domain\nencoding: raw\nspace dimension: 3\n"
                     "space directions: none (%.9g,0,0) (0,%.9g,0) (0,0,%.9g)\nspace origin: (%.9g,%.9g,%.9g)\n\n",
                     comment, channels, dims[0], dims[1], dims[2], spacing, spacing, spacing, origin[0], origin[1],
                     origin[2]);
    else
        n = snprintf(header, sizeof(header),
                     "NRRD0004\n# %s\ntype: uint8\ndimension: 3\nsizes: %u %u %u\n"
                     "kinds: domain domain domain\nencoding: raw\nspace dimension: 3\n"
                     "space directions: (%.9g,0,0) (0,%.9g,0) (0,0,%.9g)\nspace origin: (%.9g,%.9g,%.9g)\n\n",
                     comment, dims[0], dims[1], dims[2], spacing, spacing, spacing, origin[0], origin[1], origin[2]);
    if (n < 0 || (size_t)n >= sizeof(header))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: NRRD header too long", path);
    /* Rows are gathered into blocks of about 1 MiB, one write each. */
    const size_t row_bytes = (size_t)channels * dims[0];
    size_t rows_per_block = row_bytes ? ((size_t)1 << 20) / row_bytes : 1;
    if (rows_per_block < 1)
        rows_per_block = 1;
    uint8_t *block = nc_alloc(ctx, rows_per_block * row_bytes + 1);
    if (!block)
        return NACRE_ERROR_OUT_OF_MEMORY;
    nc_tmpfile tmp;
    nacre_result r = nc_tmpfile_open(ctx, path, &tmp);
    if (r == NACRE_OK)
        r = nc_tmpfile_write(ctx, &tmp, header, (size_t)n);
    size_t filled = 0;
    for (uint32_t z = 0; z < dims[2] && r == NACRE_OK; z++)
        for (uint32_t y = 0; y < dims[1] && r == NACRE_OK; y++) {
            row_fn(user, y, z, block + filled * row_bytes);
            if (++filled == rows_per_block) {
                r = nc_tmpfile_write(ctx, &tmp, block, filled * row_bytes);
                filled = 0;
            }
        }
    if (r == NACRE_OK && filled)
        r = nc_tmpfile_write(ctx, &tmp, block, filled * row_bytes);
    nc_free(ctx, block);
    if (r == NACRE_OK)
        return nc_tmpfile_commit(ctx, &tmp);
    if (tmp.tmp_path)
        nc_tmpfile_abort(ctx, &tmp);
    return r;
}

nacre_result nc_nrrd_write_f32(nacre_context *ctx, const char *path, const char *comment, const uint32_t dims[3],
                               const float spacing[3], const float origin[3], const float *data)
{
    if (!path || !data)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "nrrd: no path or data");
    /* The samples are written as they are in memory: little-endian floats. */
    _Static_assert(sizeof(float) == 4, "NRRD float samples are 4 bytes");
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "nc_nrrd_write_f32 writes memory as little-endian floats"
#endif
    char header[1024];
    /* %.9g: every float prints to a decimal that reads back as the same float. */
    int n = snprintf(header, sizeof(header),
                     "NRRD0004\n# %s\ntype: float\ndimension: 3\nsizes: %u %u %u\n"
                     "kinds: domain domain domain\nencoding: raw\nendian: little\nspace dimension: 3\n"
                     "space directions: (%.9g,0,0) (0,%.9g,0) (0,0,%.9g)\nspace origin: (%.9g,%.9g,%.9g)\n\n",
                     comment, dims[0], dims[1], dims[2], (double)spacing[0], (double)spacing[1],
                     (double)spacing[2], (double)origin[0], (double)origin[1], (double)origin[2]);
    if (n < 0 || (size_t)n >= sizeof(header))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: NRRD header too long", path);
    size_t count = (size_t)dims[0] * dims[1] * dims[2];
    nc_tmpfile tmp;
    nacre_result r = nc_tmpfile_open(ctx, path, &tmp);
    if (r == NACRE_OK)
        r = nc_tmpfile_write(ctx, &tmp, header, (size_t)n);
    if (r == NACRE_OK)
        r = nc_tmpfile_write(ctx, &tmp, data, count * sizeof(float));
    if (r == NACRE_OK)
        return nc_tmpfile_commit(ctx, &tmp);
    if (tmp.tmp_path)
        nc_tmpfile_abort(ctx, &tmp);
    return r;
}
