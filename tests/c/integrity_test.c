/* The C API's guards of a host's data (tests/capi.rs builds and runs this):
 *
 *   integrity_test DIR INPUT.exr IDS.exr
 *
 * DIR is a scratch folder. Checks that kpcn_denoise_file never erases or overwrites a
 * render (output = input, a link to it, layer names that collide with its passes), that
 * in-place writing works only when asked for, that a struct of another ABI is refused,
 * and that a frame too large for the address space fails with
 * KPCN_ERROR_OUT_OF_MEMORY instead of aborting, after which the denoiser still works.
 * IDS.exr (a frame with a uint object-id channel) is denoised to DIR/ids-denoised.exr for
 * the Rust test to compare bit for bit. Exits 0 when every check passes. */
#define _POSIX_C_SOURCE 200809L
#include <kpcn.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include "check.h"

static void copy_file(const char *from, const char *to) {
    FILE *in = fopen(from, "rb"), *out = fopen(to, "wb");
    char buf[65536];
    size_t n;
    if (!in || !out) {
        fprintf(stderr, "cannot copy %s to %s\n", from, to);
        exit(2);
    }
    while ((n = fread(buf, 1, sizeof buf, in)) > 0)
        fwrite(buf, 1, n, out);
    fclose(in);
    fclose(out);
}

static long file_size(const char *path) {
    struct stat st;
    return stat(path, &st) == 0 ? (long)st.st_size : -1;
}

/* Bytes of address space this process maps now (/proc/self/statm's first field). */
static size_t mapped_bytes(void) {
    unsigned long pages = 0;
    FILE *f = fopen("/proc/self/statm", "r");
    if (!f || fscanf(f, "%lu", &pages) != 1) {
        fprintf(stderr, "cannot read /proc/self/statm\n");
        exit(2);
    }
    fclose(f);
    return (size_t)pages * (size_t)sysconf(_SC_PAGESIZE);
}

static void files(const char *dir, const char *example, const char *ids) {
    char a[4096], link[4096], out[4096];
    KpcnDenoiser *d = NULL;
    KpcnFileOptions fo;
    long size;
    snprintf(a, sizeof a, "%s/render.exr", dir);
    snprintf(link, sizeof link, "%s/link.exr", dir);
    snprintf(out, sizeof out, "%s/out.exr", dir);
    copy_file(example, a);
    size = file_size(a);
    EXPECT(kpcn_denoiser_new(NULL, &d), KPCN_OK);

    /* The render itself as a separate output: it would be erased. */
    EXPECT(kpcn_file_options_init(&fo), KPCN_OK);
    fo.separate = true;
    EXPECT(kpcn_denoise_file(d, a, a, &fo), KPCN_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(kpcn_last_error(), "erased") != NULL, "says why: %s", kpcn_last_error());
    fo.in_place = true;
    EXPECT(kpcn_denoise_file(d, a, a, &fo), KPCN_ERROR_INVALID_ARGUMENT);
    CHECK(file_size(a) == size, "the render is untouched");

    /* The render, directly or through a link, without in-place: refused. */
    EXPECT(kpcn_denoise_file(d, a, a, NULL), KPCN_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(kpcn_last_error(), "in_place") != NULL, "names the option: %s", kpcn_last_error());
    CHECK(symlink("render.exr", link) == 0, "symlink");
    EXPECT(kpcn_denoise_file(d, a, link, NULL), KPCN_ERROR_INVALID_ARGUMENT);
    CHECK(file_size(a) == size, "the render is untouched");

    /* A struct from a host built against another ABI (here: before `in_place` existed,
     * 24 bytes) is refused, never half read. */
    EXPECT(kpcn_file_options_init(&fo), KPCN_OK);
    fo.struct_size = 24;
    EXPECT(kpcn_denoise_file(d, a, a, &fo), KPCN_ERROR_UNSUPPORTED_VERSION);

    /* Layer names that would overwrite a pass, or name nothing. */
    EXPECT(kpcn_file_options_init(&fo), KPCN_OK);
    fo.layer = "albedo";
    EXPECT(kpcn_denoise_file(d, a, out, &fo), KPCN_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(kpcn_last_error(), "albedo.R") != NULL, "names the pass: %s", kpcn_last_error());
    fo.layer = "";
    EXPECT(kpcn_denoise_file(d, a, out, &fo), KPCN_ERROR_INVALID_ARGUMENT);
    CHECK(access(out, F_OK) != 0, "nothing written");

    /* A frame with object ids: denoised through the library, checked by the caller. */
    snprintf(out, sizeof out, "%s/ids-denoised.exr", dir);
    EXPECT(kpcn_denoise_file(d, ids, out, NULL), KPCN_OK);

    /* Asked for, in place works: the render gains the denoised layer. */
    EXPECT(kpcn_file_options_init(&fo), KPCN_OK);
    fo.in_place = true;
    EXPECT(kpcn_denoise_file(d, a, a, &fo), KPCN_OK);
    CHECK(file_size(a) > size, "the layer was added (%ld -> %ld bytes)", size, file_size(a));
    EXPECT(kpcn_denoiser_free(d), KPCN_OK);
}

/* A frame whose working memory the address space cannot hold. */
static void out_of_memory(void) {
    const size_t w = 2048, h = 2048;
    float *px = calloc(w * h * 3, sizeof(float));
    float *out = calloc(w * h * 3, sizeof(float));
    const char *rgb[] = {"color", "diffuse", "specular", "albedo", "normal"};
    const char *scalar[] = {"depth", "colorVariance"};
    KpcnDenoiser *d = NULL;
    KpcnOptions o;
    struct rlimit old, tight;
    size_t i;
    if (!px || !out) {
        fprintf(stderr, "cannot allocate the host's frame\n");
        exit(2);
    }
    EXPECT(kpcn_options_init(&o), KPCN_OK);
    o.threads = 1;
    EXPECT(kpcn_denoiser_new(&o, &d), KPCN_OK);
    for (i = 0; i < 5; ++i)
        EXPECT(kpcn_set_image(d, rgb[i], px, KPCN_FORMAT_FLOAT3, w, h, 0, 0), KPCN_OK);
    for (i = 0; i < 2; ++i)
        EXPECT(kpcn_set_image(d, scalar[i], px, KPCN_FORMAT_FLOAT, w, h, 12, 0), KPCN_OK);
    EXPECT(kpcn_set_image(d, "output", out, KPCN_FORMAT_FLOAT3, w, h, 0, 0), KPCN_OK);

    /* 256 MB more than is mapped now: far less than a 4-Mpixel frame needs (≈1 GB). */
    CHECK(getrlimit(RLIMIT_AS, &old) == 0, "getrlimit");
    tight = old;
    tight.rlim_cur = (rlim_t)(mapped_bytes() + ((size_t)256 << 20));
    CHECK(setrlimit(RLIMIT_AS, &tight) == 0, "setrlimit");
    out[0] = 42.0f;
    EXPECT(kpcn_execute(d), KPCN_ERROR_OUT_OF_MEMORY);
    CHECK(strstr(kpcn_last_error(), "max_memory_mb") != NULL, "says what to do: %s", kpcn_last_error());
    CHECK(out[0] == 42.0f, "the output image is untouched");
    CHECK(strcmp(kpcn_status_string(KPCN_ERROR_OUT_OF_MEMORY), "out of memory") == 0, "status string");
    CHECK(setrlimit(RLIMIT_AS, &old) == 0, "restore the limit");

    /* The same denoiser still works once memory is there (a small frame). */
    for (i = 0; i < 5; ++i)
        EXPECT(kpcn_set_image(d, rgb[i], px, KPCN_FORMAT_FLOAT3, 64, 64, 0, 0), KPCN_OK);
    for (i = 0; i < 2; ++i)
        EXPECT(kpcn_set_image(d, scalar[i], px, KPCN_FORMAT_FLOAT, 64, 64, 12, 0), KPCN_OK);
    EXPECT(kpcn_set_image(d, "output", out, KPCN_FORMAT_FLOAT3, 64, 64, 0, 0), KPCN_OK);
    EXPECT(kpcn_execute(d), KPCN_OK);
    EXPECT(kpcn_denoiser_free(d), KPCN_OK);
    free(px);
    free(out);
}

int main(int argc, char **argv) {
    if (argc != 4) {
        fprintf(stderr, "usage: integrity_test DIR INPUT.exr IDS.exr\n");
        return 2;
    }
    files(argv[1], argv[2], argv[3]);
    out_of_memory();
    if (failures) {
        fprintf(stderr, "%d check(s) failed\n", failures);
        return 1;
    }
    printf("all checks passed\n");
    return 0;
}
