/* A C host denoising its own W x H buffers through the C ABI (benches/throughput.sh):
 * prints seconds and what kpcn added to the process's peak RSS beyond the host's images.
 *   capi_host W H MAX_MEMORY_MB THREADS */
#include <kpcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>

static long peak_kb(void) {
    struct rusage u;
    getrusage(RUSAGE_SELF, &u);
    return u.ru_maxrss;
}

int main(int argc, char **argv) {
    if (argc != 5) {
        fprintf(stderr, "usage: capi_host W H MAX_MEMORY_MB THREADS\n");
        return 2;
    }
    size_t w = strtoul(argv[1], NULL, 10), h = strtoul(argv[2], NULL, 10), i;
    float *rgb = malloc(w * h * 12), *dif = malloc(w * h * 12), *alb = malloc(w * h * 12);
    float *nrm = malloc(w * h * 12), *z = malloc(w * h * 4), *out = malloc(w * h * 12);
    if (!rgb || !dif || !alb || !nrm || !z || !out) return 2;
    srand(1);
    for (i = 0; i < w * h * 3; ++i) {
        float noise = (float)rand() / RAND_MAX;
        alb[i] = 0.5f;
        dif[i] = 0.5f * noise;
        rgb[i] = dif[i] + 0.1f * noise * noise;
        nrm[i] = i % 3 == 2 ? 1.0f : 0.0f;
        out[i] = 0.0f;
    }
    for (i = 0; i < w * h; ++i) z[i] = 1.0f + (float)(i % w) / w;
    long before = peak_kb();
    KpcnOptions o;
    kpcn_options_init(&o);
    o.model_name = "auto";
    o.max_memory_mb = atoi(argv[3]);
    o.threads = atoi(argv[4]);
    KpcnDenoiser *d = NULL;
    if (kpcn_denoiser_new(&o, &d) != KPCN_OK) {
        fprintf(stderr, "%s\n", kpcn_last_error());
        return 1;
    }
    kpcn_set_image(d, "color", rgb, KPCN_FORMAT_FLOAT3, w, h, 0, 0);
    kpcn_set_image(d, "diffuse", dif, KPCN_FORMAT_FLOAT3, w, h, 0, 0);
    kpcn_set_image(d, "albedo", alb, KPCN_FORMAT_FLOAT3, w, h, 0, 0);
    kpcn_set_image(d, "normal", nrm, KPCN_FORMAT_FLOAT3, w, h, 0, 0);
    kpcn_set_image(d, "depth", z, KPCN_FORMAT_FLOAT, w, h, 0, 0);
    kpcn_set_image(d, "output", out, KPCN_FORMAT_FLOAT3, w, h, 0, 0);
    struct timespec t0, t1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    if (kpcn_execute(d) != KPCN_OK) {
        fprintf(stderr, "%s\n", kpcn_last_error());
        return 1;
    }
    clock_gettime(CLOCK_MONOTONIC, &t1);
    printf("%.2f s, kpcn added %ld MB to the host's %zu MB of images\n",
           (t1.tv_sec - t0.tv_sec) + (t1.tv_nsec - t0.tv_nsec) * 1e-9, (peak_kb() - before) / 1024,
           (w * h * (12 * 5 + 4)) >> 20);
    kpcn_denoiser_free(d);
    return 0;
}
