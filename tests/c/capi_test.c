/* The C API from C99, as a host uses it (tests/capi.rs builds and runs this).
 *
 *   capi_test DIR W H INPUT.exr
 *
 * DIR holds the frame's images as raw little-endian arrays written by the Rust test
 * (NAME.f32: packed floats; albedo.f16: packed halves). Writes DIR/output.f32,
 * DIR/outputDiffuse.f32, DIR/outputSpecular.f32 (in memory) and DIR/file.exr (file call).
 * Exits 0 when every check passes; prints the first failure otherwise. */
#include <kpcn.h>

#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "check.h"

static const char *dir;
static size_t W, H;

static void *load(const char *name, size_t bytes) {
    char path[4096];
    void *p = malloc(bytes);
    FILE *f;
    snprintf(path, sizeof path, "%s/%s", dir, name);
    f = fopen(path, "rb");
    if (!f || !p || fread(p, 1, bytes, f) != bytes) {
        fprintf(stderr, "cannot read %s\n", path);
        exit(2);
    }
    fclose(f);
    return p;
}

static void save(const char *name, const void *p, size_t bytes) {
    char path[4096];
    FILE *f;
    snprintf(path, sizeof path, "%s/%s", dir, name);
    f = fopen(path, "wb");
    if (!f || fwrite(p, 1, bytes, f) != bytes) {
        fprintf(stderr, "cannot write %s\n", path);
        exit(2);
    }
    fclose(f);
}

/* The frame's inputs in assorted host formats, and three outputs. */
typedef struct {
    float *color4;     /* RGBA floats, rows stored bottom-up */
    float *diffuse, *specular, *normal, *depth;
    unsigned short *albedo16;
    float *variance[6];
    float *out, *out_diffuse4, *out_specular;
} Frame;

static const char *variance_names[6] = {"colorVariance", "diffuseVariance", "specularVariance",
                                   "albedoVariance", "normalVariance", "depthVariance"};

static Frame load_frame(void) {
    Frame f;
    size_t n = W * H, y, x, c, i;
    float *color = load("color.f32", n * 3 * sizeof(float));
    f.color4 = malloc(n * 4 * sizeof(float));
    for (y = 0; y < H; y++)
        for (x = 0; x < W; x++) {
            float *px = f.color4 + ((H - 1 - y) * W + x) * 4;
            for (c = 0; c < 3; c++) px[c] = color[(y * W + x) * 3 + c];
            px[3] = 1.0f;
        }
    free(color);
    f.diffuse = load("diffuse.f32", n * 3 * sizeof(float));
    f.specular = load("specular.f32", n * 3 * sizeof(float));
    f.normal = load("normal.f32", n * 3 * sizeof(float));
    f.depth = load("depth.f32", n * sizeof(float));
    f.albedo16 = load("albedo.f16", n * 3 * 2);
    for (i = 0; i < 6; i++) {
        char name[64];
        snprintf(name, sizeof name, "%s.f32", variance_names[i]);
        f.variance[i] = load(name, n * sizeof(float));
    }
    f.out = calloc(n * 3, sizeof(float));
    /* 4 floats per pixel and 16 bytes of padding per row. */
    f.out_diffuse4 = calloc(H * (W * 4 + 4), sizeof(float));
    f.out_specular = calloc(n * 3, sizeof(float));
    return f;
}

static void free_frame(Frame *f) {
    int i;
    free(f->color4);
    free(f->diffuse);
    free(f->specular);
    free(f->normal);
    free(f->depth);
    free(f->albedo16);
    for (i = 0; i < 6; i++) free(f->variance[i]);
    free(f->out);
    free(f->out_diffuse4);
    free(f->out_specular);
}

static KpcnStatus set_images(KpcnDenoiser *d, Frame *f, bool variances) {
    ptrdiff_t row4 = (ptrdiff_t)(W * 4 * sizeof(float));
    KpcnStatus s = KPCN_OK;
    int i;
#define SET(...) if (s == KPCN_OK) s = kpcn_set_image(d, __VA_ARGS__)
    /* Bottom-up rows: the top row is the last in memory, the row stride negative. */
    SET("color", f->color4 + (H - 1) * W * 4, KPCN_FORMAT_FLOAT4, W, H, 0, -row4);
    SET("diffuse", f->diffuse, KPCN_FORMAT_FLOAT3, W, H, 0, 0);
    SET("specular", f->specular, KPCN_FORMAT_FLOAT3, W, H, 12, 0);
    SET("albedo", f->albedo16, KPCN_FORMAT_HALF3, W, H, 0, 0);
    SET("normal", f->normal, KPCN_FORMAT_FLOAT3, W, H, 0, 0);
    SET("depth", f->depth, KPCN_FORMAT_FLOAT, W, H, 0, 0);
    for (i = 0; variances && i < 6; i++) SET(variance_names[i], f->variance[i], KPCN_FORMAT_FLOAT, W, H, 0, 0);
    SET("output", f->out, KPCN_FORMAT_FLOAT3, W, H, 0, 0);
    SET("outputDiffuse", f->out_diffuse4, KPCN_FORMAT_FLOAT4, W, H, 16,
                        (ptrdiff_t)((W * 4 + 4) * sizeof(float)));
    SET("outputSpecular", f->out_specular, KPCN_FORMAT_FLOAT3, W, H, 0, 0);
#undef SET
    return s;
}

static KpcnStatus set_frame(KpcnDenoiser *d, Frame *f) { return set_images(d, f, true); }

static KpcnDenoiser *new_denoiser(unsigned threads) {
    KpcnOptions o;
    KpcnDenoiser *d = NULL;
    EXPECT(kpcn_options_init(&o), KPCN_OK);
    o.threads = threads;
    EXPECT(kpcn_denoiser_new(&o, &d), KPCN_OK);
    return d;
}

typedef struct {
    pthread_t caller;
    int calls, wrong_thread, cancel_at;
    double last;
} Progress;

static bool on_progress(void *user, double fraction) {
    Progress *p = user;
    p->calls++;
    if (!pthread_equal(pthread_self(), p->caller)) p->wrong_thread++;
    CHECK(fraction >= p->last && fraction <= 1.0, "progress %g after %g", fraction, p->last);
    p->last = fraction;
    return p->cancel_at == 0 || p->calls < p->cancel_at;
}

typedef struct {
    int calls;
    KpcnStatus status;
    char message[512];
} Errors;

static void on_error(void *user, KpcnStatus status, const char *message) {
    Errors *e = user;
    e->calls++;
    e->status = status;
    snprintf(e->message, sizeof e->message, "%s", message);
}

static void misuse(void) {
    KpcnDenoiser *d = NULL;
    KpcnOptions o;
    float px[12] = {0};
    Errors errors = {0, KPCN_OK, ""};

    EXPECT(kpcn_denoiser_new(NULL, NULL), KPCN_ERROR_INVALID_ARGUMENT);
    EXPECT(kpcn_options_init(NULL), KPCN_ERROR_INVALID_ARGUMENT);
    EXPECT(kpcn_denoiser_free(NULL), KPCN_OK);
    EXPECT(kpcn_execute(NULL), KPCN_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(kpcn_last_error(), "NULL") != NULL, "message: %s", kpcn_last_error());

    kpcn_options_init(&o);
    o.struct_size = 8;
    EXPECT(kpcn_denoiser_new(&o, &d), KPCN_ERROR_UNSUPPORTED_VERSION);
    CHECK(d == NULL, "a failed new leaves *out NULL");
    kpcn_options_init(&o);
    o.model_name = "small";
    EXPECT(kpcn_denoiser_new(&o, &d), KPCN_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(kpcn_last_error(), "untrained") != NULL, "message: %s", kpcn_last_error());
    o.model_name = "no-such-model";
    EXPECT(kpcn_denoiser_new(&o, &d), KPCN_ERROR_MODEL);
    o.model_name = NULL;
    o.model_path = "/nonexistent/model.safetensors";
    EXPECT(kpcn_denoiser_new(&o, &d), KPCN_ERROR_MODEL);
    CHECK(strstr(kpcn_last_error(), "/nonexistent/model.safetensors") != NULL, "names the file: %s",
          kpcn_last_error());

    EXPECT(kpcn_denoiser_new(NULL, &d), KPCN_OK);
    EXPECT(kpcn_set_error_callback(d, on_error, &errors), KPCN_OK);
    EXPECT(kpcn_execute(d), KPCN_ERROR_INVALID_STATE); /* before any input */
    CHECK(errors.calls == 1 && errors.status == KPCN_ERROR_INVALID_STATE, "error callback: %d calls", errors.calls);
    CHECK(strstr(errors.message, "no input") != NULL, "callback message: %s", errors.message);
    EXPECT(kpcn_set_image(d, NULL, px, KPCN_FORMAT_FLOAT3, 2, 2, 0, 0), KPCN_ERROR_INVALID_ARGUMENT);
    EXPECT(kpcn_set_image(d, "color", NULL, KPCN_FORMAT_FLOAT3, 2, 2, 0, 0), KPCN_ERROR_INVALID_ARGUMENT);
    EXPECT(kpcn_set_image(d, "colour", px, KPCN_FORMAT_FLOAT3, 2, 2, 0, 0), KPCN_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(kpcn_last_error(), "unknown image `colour`") != NULL, "message: %s", kpcn_last_error());
    EXPECT(kpcn_set_image(d, "color", px, 99, 2, 2, 0, 0), KPCN_ERROR_INVALID_ARGUMENT);
    EXPECT(kpcn_set_image(d, "color", px, KPCN_FORMAT_FLOAT3, 2, 2, 4, 0), KPCN_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(kpcn_last_error(), "pixel stride 4") != NULL, "message: %s", kpcn_last_error());
    EXPECT(kpcn_set_image(d, "color", px, KPCN_FORMAT_FLOAT3, 2, 2, 12, 8), KPCN_ERROR_INVALID_ARGUMENT);
    EXPECT(kpcn_set_image(d, "color", px, KPCN_FORMAT_FLOAT, 2, 2, 0, 0), KPCN_ERROR_INVALID_ARGUMENT);
    EXPECT(kpcn_set_image(d, "color", px, KPCN_FORMAT_FLOAT3, 0, 2, 0, 0), KPCN_ERROR_INVALID_ARGUMENT);
    EXPECT(kpcn_unset_image(d, "albedo"), KPCN_ERROR_INVALID_ARGUMENT);
    EXPECT(kpcn_set_image(d, "color", px, KPCN_FORMAT_FLOAT3, 2, 2, 0, 0), KPCN_OK);
    EXPECT(kpcn_set_image(d, "output", px, KPCN_FORMAT_FLOAT3, 2, 2, 0, 0), KPCN_OK);
    EXPECT(kpcn_execute(d), KPCN_ERROR_INVALID_STATE); /* albedo, normal, … missing */
    CHECK(strstr(kpcn_last_error(), "albedo") != NULL && strstr(kpcn_last_error(), "depth") != NULL,
          "names the missing inputs: %s", kpcn_last_error());
    EXPECT(kpcn_set_image(d, "diffuse", px, KPCN_FORMAT_FLOAT3, 1, 2, 0, 0), KPCN_OK);
    EXPECT(kpcn_execute(d), KPCN_ERROR_INVALID_STATE); /* sizes disagree */
    CHECK(strstr(kpcn_last_error(), "1x2") != NULL, "message: %s", kpcn_last_error());
    EXPECT(kpcn_unset_image(d, "diffuse"), KPCN_OK);
    EXPECT(kpcn_denoise_file(d, "/nonexistent/in.exr", "/tmp/out.exr", NULL), KPCN_ERROR_IO);
    CHECK(strstr(kpcn_last_error(), "/nonexistent/in.exr") != NULL, "names the file: %s", kpcn_last_error());
    {
        KpcnFileOptions fo;
        EXPECT(kpcn_file_options_init(&fo), KPCN_OK);
        fo.layout = 42;
        EXPECT(kpcn_denoise_file(d, "/nonexistent/in.exr", "/tmp/out.exr", &fo), KPCN_ERROR_INVALID_ARGUMENT);
    }
    EXPECT(kpcn_denoiser_free(d), KPCN_OK);
    EXPECT(kpcn_denoiser_free(d), KPCN_ERROR_INVALID_STATE); /* double free, guarded */
    EXPECT(kpcn_execute(d), KPCN_ERROR_INVALID_STATE);       /* use after free, guarded */
    EXPECT(kpcn_execute((KpcnDenoiser *)px), KPCN_ERROR_INVALID_STATE);
    CHECK(strcmp(kpcn_status_string(12345), "unknown status") == 0, "%s", kpcn_status_string(12345));
}

/* Each thread fails differently and must read back its own message. */
static void *error_thread(void *arg) {
    const char *name = arg;
    int i;
    for (i = 0; i < 200; i++) {
        kpcn_set_image(NULL, name, NULL, 0, 0, 0, 0, 0);
        kpcn_denoiser_new(NULL, NULL);
        if (strstr(kpcn_last_error(), "out is NULL") == NULL) return (void *)1;
        kpcn_execute(NULL);
        if (strstr(kpcn_last_error(), "denoiser is NULL") == NULL) return (void *)1;
    }
    return NULL;
}

typedef struct {
    Frame frame;
    KpcnStatus status;
} Job;

static void *denoise_thread(void *arg) {
    Job *job = arg;
    KpcnDenoiser *d = new_denoiser(1);
    job->frame = load_frame();
    job->status = set_frame(d, &job->frame);
    if (job->status == KPCN_OK) job->status = kpcn_execute(d);
    kpcn_denoiser_free(d);
    return NULL;
}

int main(int argc, char **argv) {
    KpcnDenoiser *d;
    Frame f;
    Progress p;
    size_t n, y, x, c;
    char path[4096];
    float *beauty;

    if (argc != 5) {
        fprintf(stderr, "usage: capi_test DIR W H INPUT.exr\n");
        return 2;
    }
    dir = argv[1];
    W = (size_t)atol(argv[2]);
    H = (size_t)atol(argv[3]);
    n = W * H;
    printf("kpcn %s (%u)\n", kpcn_version_string(), kpcn_version());
    CHECK(kpcn_version() >= 100, "version %u", kpcn_version());

    misuse();

    /* In memory, with progress on the calling thread. */
    d = new_denoiser(2);
    f = load_frame();
    EXPECT(set_frame(d, &f), KPCN_OK);
    p.caller = pthread_self();
    p.calls = p.wrong_thread = p.cancel_at = 0;
    p.last = 0.0;
    EXPECT(kpcn_set_progress_callback(d, on_progress, &p), KPCN_OK);
    EXPECT(kpcn_execute(d), KPCN_OK);
    CHECK(p.calls >= 1 && p.last == 1.0, "%d progress calls, last %g", p.calls, p.last);
    CHECK(p.wrong_thread == 0, "%d progress calls off the caller's thread", p.wrong_thread);
    save("output.f32", f.out, n * 3 * sizeof(float));
    save("outputSpecular.f32", f.out_specular, n * 3 * sizeof(float));
    {
        float *packed = malloc(n * 3 * sizeof(float));
        for (y = 0; y < H; y++)
            for (x = 0; x < W; x++)
                for (c = 0; c < 3; c++) packed[(y * W + x) * 3 + c] = f.out_diffuse4[y * (W * 4 + 4) + x * 4 + c];
        save("outputDiffuse.f32", packed, n * 3 * sizeof(float));
        free(packed);
    }

    beauty = malloc(n * 3 * sizeof(float));
    memcpy(beauty, f.out, n * 3 * sizeof(float));

    /* Cancel from the progress callback: a status, and the outputs untouched. */
    memset(f.out, 0xff, n * 3 * sizeof(float));
    p.calls = 0;
    p.last = 0.0;
    p.cancel_at = 1;
    EXPECT(kpcn_execute(d), KPCN_ERROR_CANCELLED);
    CHECK(p.calls == 1, "%d calls after cancelling", p.calls);
    for (x = 0; x < n * 3; x++)
        if (((unsigned *)f.out)[x] != 0xffffffffu) {
            CHECK(0, "output written by a cancelled call");
            break;
        }
    EXPECT(kpcn_set_progress_callback(d, NULL, NULL), KPCN_OK);

    /* The file call. */
    snprintf(path, sizeof path, "%s/file.exr", dir);
    EXPECT(kpcn_denoise_file(d, argv[4], path, NULL), KPCN_OK);
    EXPECT(kpcn_denoiser_free(d), KPCN_OK);

    /* Two denoisers on two threads give the same images; errors stay per thread. */
    {
        Job jobs[2];
        pthread_t t[2], e[2];
        void *r[2];
        int i;
        pthread_create(&e[0], NULL, error_thread, "a");
        pthread_create(&e[1], NULL, error_thread, "b");
        for (i = 0; i < 2; i++) pthread_create(&t[i], NULL, denoise_thread, &jobs[i]);
        for (i = 0; i < 2; i++) pthread_join(t[i], NULL);
        for (i = 0; i < 2; i++) pthread_join(e[i], &r[i]);
        CHECK(r[0] == NULL && r[1] == NULL, "a thread read another thread's error");
        for (i = 0; i < 2; i++) {
            EXPECT(jobs[i].status, KPCN_OK);
            CHECK(memcmp(jobs[i].frame.out, beauty, n * 3 * sizeof(float)) == 0, "thread %d's beauty differs", i);
            CHECK(memcmp(jobs[i].frame.out_specular, f.out_specular, n * 3 * sizeof(float)) == 0,
                  "thread %d's specular differs", i);
            free_frame(&jobs[i].frame);
        }
    }
    /* Model "auto": with a colorVariance image it is `default` (the beauty above); without
       variances, `spatial`, exactly as naming it. */
    {
        const char *models[2] = {"auto", "spatial"};
        Frame g[3];
        int i;
        for (i = 0; i < 3; i++) {
            KpcnOptions o;
            KpcnDenoiser *a = NULL;
            EXPECT(kpcn_options_init(&o), KPCN_OK);
            o.threads = 2;
            o.model_name = models[i == 2];
            EXPECT(kpcn_denoiser_new(&o, &a), KPCN_OK);
            g[i] = load_frame();
            EXPECT(set_images(a, &g[i], i == 0), KPCN_OK);
            EXPECT(kpcn_execute(a), KPCN_OK);
            EXPECT(kpcn_denoiser_free(a), KPCN_OK);
        }
        CHECK(memcmp(g[0].out, beauty, n * 3 * sizeof(float)) == 0, "auto with variances is not `default`");
        CHECK(memcmp(g[1].out, g[2].out, n * 3 * sizeof(float)) == 0, "auto without variances is not `spatial`");
        for (i = 0; i < 3; i++) free_frame(&g[i]);
    }
    free_frame(&f);
    free(beauty);
    if (failures) {
        fprintf(stderr, "%d checks failed\n", failures);
        return 1;
    }
    printf("all checks passed\n");
    return 0;
}
