/* kpcn's thin C shim over OpenImageIO 2.4 (Debian 12).
 *
 * Every function returns 0 on success and -1 on failure (KPCN_SHIM_OUT_OF_MEMORY when an
 * allocation failed); on failure the text of
 * the error (OpenImageIO's geterror() or the caught C++ exception) is available
 * from kpcn_oiio_last_error() on the same thread until the next shim call.
 * No C++ exception ever leaves this file.
 */
#ifndef KPCN_OIIO_SHIM_H
#define KPCN_OIIO_SHIM_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* The status of a call that ran out of memory (std::bad_alloc). */
#define KPCN_SHIM_OUT_OF_MEMORY -2

/* Per-channel sample formats we distinguish. */
enum kpcn_format {
    KPCN_FORMAT_OTHER = 0,
    KPCN_FORMAT_HALF = 1,
    KPCN_FORMAT_FLOAT = 2,
    KPCN_FORMAT_UINT = 3
};

/* An opened image file; all subimage specs are read at open time. */
typedef struct kpcn_input kpcn_input;

/* Geometry of one subimage (an EXR part). */
typedef struct kpcn_subimage_info {
    int x, y, width, height;                /* data window */
    int full_x, full_y, full_width, full_height; /* display window */
    int nchannels;
    int tile_width, tile_height;            /* 0 for scanline images */
    int deep;                               /* nonzero for deep images (unsupported) */
} kpcn_subimage_info;

/* One metadata attribute. Pointers stay valid while the input is open. */
typedef struct kpcn_attribute {
    const char* name;
    const char* type;      /* OpenImageIO TypeDesc spelling, e.g. "float", "string", "matrix" */
    const void* data;      /* raw value bytes (NULL for strings) */
    size_t size;           /* bytes at data */
    const char* text;      /* the value as text (always set) */
    int is_string;         /* a single string: write it back from `text` */
} kpcn_attribute;

/* The last error of this thread, never NULL. */
const char* kpcn_oiio_last_error(void);

/* OpenImageIO's version as an integer, e.g. 20407. */
int kpcn_oiio_version(void);

/* Sets OpenImageIO's global attribute `exr_threads` (OpenEXR's codec thread pool; -1 = none). */
int kpcn_oiio_set_exr_threads(int n);

/* Opens `path`; with `openexr_core` nonzero an EXR is read by OpenImageIO's OpenEXRCore
 * reader (`openexr:core`), decoding on the calling thread. */
int kpcn_input_open(const char* path, int openexr_core, kpcn_input** out);
void kpcn_input_close(kpcn_input* in);
const char* kpcn_input_format_name(const kpcn_input* in);
int kpcn_input_subimages(const kpcn_input* in);
int kpcn_input_subimage_info(const kpcn_input* in, int subimage, kpcn_subimage_info* info);
/* Part name ("name" attribute) or "" when absent. */
const char* kpcn_input_subimage_name(const kpcn_input* in, int subimage);
const char* kpcn_input_channel_name(const kpcn_input* in, int subimage, int channel);
int kpcn_input_channel_format(const kpcn_input* in, int subimage, int channel);
int kpcn_input_attribute_count(const kpcn_input* in, int subimage);
int kpcn_input_attribute(const kpcn_input* in, int subimage, int index, kpcn_attribute* attr);
/* Reads rows [ybegin, yend) (absolute data-window coordinates) of channels
 * [chbegin, chend) as interleaved f32 into `data` (UINT channels as their bits: a
 * bit-cast, not a conversion), which holds
 * (yend-ybegin) * width * (chend-chbegin) floats. For tiled images, ybegin and
 * yend must lie on tile boundaries or the data window's end. */
int kpcn_input_read_rows(kpcn_input* in, int subimage, int ybegin, int yend,
                         int chbegin, int chend, float* data);

/* An EXR being written: open, write rows in order, close. */
typedef struct kpcn_output kpcn_output;

typedef struct kpcn_output_spec {
    const char* part_name;        /* EXR part name; NULL or "" for none */
    int x, y, width, height;
    int full_x, full_y, full_width, full_height;
    int nchannels;
    const char* const* channel_names;
    const int* channel_formats;   /* kpcn_format: HALF, FLOAT or UINT (others are written as FLOAT) */
    const char* compression;      /* e.g. "zip", "piz", "none"; NULL for the default */
    const kpcn_attribute* attributes;
    int nattributes;
} kpcn_output_spec;

/* Opens an EXR of `nparts` parts (1 = an ordinary single-part file) and starts part 0. */
/* `encoders` > 1 compresses on that many threads of OpenEXR's pool (process-wide: it
   stays that size until OIIO next sizes it); 0 or 1 leaves the pool as the process set it. */
int kpcn_output_open(const char* path, const kpcn_output_spec* specs, int nparts, int encoders,
                     kpcn_output** out);
/* Finishes the current part and starts the next one. */
int kpcn_output_next_part(kpcn_output* out);
/* Rows [ybegin, yend) of the current part, all its channels interleaved as f32, in order;
 * UINT channels as their bits, as kpcn_input_read_rows gives them. */
int kpcn_output_write_rows(kpcn_output* out, int ybegin, int yend, const float* data);
/* Closes the file (flushing it) and frees the handle; safe on NULL. */
int kpcn_output_close(kpcn_output* out);

#ifdef __cplusplus
}
#endif
#endif
