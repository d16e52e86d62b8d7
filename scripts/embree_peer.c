// The Embree peer of `dcrt bench rays --peer embree`: traces the same camera rays through the same
// triangles with Embree 3 on every core, so that dcrt's rate can be set against it in one run.
//
// Input directory (written by dcrt):
//   mesh.bin    u32 triangle count n, then n x 9 f32 (v0, v1, v2), little-endian, input order
//   camera.txt  width height runs, then origin, forward, right, up (3 floats each)
// Output: hits.bin (u32 primitive id per pixel, row-major, y down; 0xffffffff on a miss) and one
// JSON line on stdout.
//
// A pixel's ray is d = normalize(forward + sx right + sy up) with sx = 2 (x + 0.5) / width - 1 and
// sy = 1 - 2 (y + 0.5) / height, in f32, as dcrt's raygen makes it. Each thread takes 8x8 tiles
// from a shared counter and traces them as eight rtcIntersect8 packets, one per tile row.
#include <embree3/rtcore.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

static unsigned width, height, runs;
static float org[3], fwd[3], right_[3], up[3];
static RTCScene scene;
static uint32_t *hits;
static atomic_uint next_tile;
static unsigned tiles_x, tiles_y;

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void die(const char *what) {
    fprintf(stderr, "embree peer: %s\n", what);
    exit(1);
}

static void *worker(void *arg) {
    (void)arg;
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    for (;;) {
        unsigned tile = atomic_fetch_add(&next_tile, 1);
        if (tile >= tiles_x * tiles_y) break;
        unsigned x0 = (tile % tiles_x) * 8, y0 = (tile / tiles_x) * 8;
        for (unsigned y = y0; y < y0 + 8 && y < height; y++) {
            struct RTCRayHit8 rh __attribute__((aligned(32)));
            int valid[8] __attribute__((aligned(32)));
            for (unsigned i = 0; i < 8; i++) {
                unsigned x = x0 + i;
                valid[i] = x < width ? -1 : 0;
                float sx = 2.0f * ((float)x + 0.5f) / (float)width - 1.0f;
                float sy = 1.0f - 2.0f * ((float)y + 0.5f) / (float)height;
                float d[3];
                for (int k = 0; k < 3; k++) d[k] = fwd[k] + sx * right_[k] + sy * up[k];
                float l = sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
                rh.ray.org_x[i] = org[0];
                rh.ray.org_y[i] = org[1];
                rh.ray.org_z[i] = org[2];
                rh.ray.dir_x[i] = d[0] / l;
                rh.ray.dir_y[i] = d[1] / l;
                rh.ray.dir_z[i] = d[2] / l;
                rh.ray.tnear[i] = 0.0f;
                rh.ray.tfar[i] = INFINITY;
                rh.ray.time[i] = 0.0f;
                rh.ray.mask[i] = -1;
                rh.ray.id[i] = i;
                rh.ray.flags[i] = 0;
                rh.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
                rh.hit.primID[i] = RTC_INVALID_GEOMETRY_ID;
            }
            rtcIntersect8(valid, scene, &ctx, &rh);
            for (unsigned i = 0; i < 8 && x0 + i < width; i++) {
                uint32_t id = rh.hit.geomID[i] == RTC_INVALID_GEOMETRY_ID ? 0xffffffffu : rh.hit.primID[i];
                hits[(size_t)y * width + x0 + i] = id;
            }
        }
    }
    return NULL;
}

static int cmp(const void *a, const void *b) {
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

int main(int argc, char **argv) {
    if (argc != 2) die("usage: embree_peer DIR");
    char path[4096];
    snprintf(path, sizeof path, "%s/camera.txt", argv[1]);
    FILE *f = fopen(path, "r");
    if (!f) die("cannot open camera.txt");
    if (fscanf(f, "%u %u %u %f %f %f %f %f %f %f %f %f %f %f %f", &width, &height, &runs, &org[0],
               &org[1], &org[2], &fwd[0], &fwd[1], &fwd[2], &right_[0], &right_[1], &right_[2],
               &up[0], &up[1], &up[2]) != 15)
        die("camera.txt: expected width height runs and 4 vectors");
    fclose(f);
    if (width == 0 || height == 0 || runs == 0) die("camera.txt: zero width, height or runs");
    snprintf(path, sizeof path, "%s/mesh.bin", argv[1]);
    f = fopen(path, "rb");
    if (!f) die("cannot open mesh.bin");
    uint32_t n;
    if (fread(&n, 4, 1, f) != 1) die("mesh.bin: no triangle count");

    RTCDevice device = rtcNewDevice(NULL);
    if (!device) die("rtcNewDevice failed");
    double t0 = now();
    scene = rtcNewScene(device);
    RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    float *v = rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                       3 * sizeof(float), (size_t)n * 3);
    uint32_t *ix = rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                           3 * sizeof(uint32_t), n);
    if (!v || !ix) die("cannot allocate the geometry buffers");
    if (fread(v, 4, (size_t)n * 9, f) != (size_t)n * 9) die("mesh.bin: truncated");
    fclose(f);
    for (uint32_t i = 0; i < 3 * n; i++) ix[i] = i;
    rtcCommitGeometry(geom);
    rtcAttachGeometry(scene, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(scene);
    double build_ms = (now() - t0) * 1e3;

    long threads = sysconf(_SC_NPROCESSORS_ONLN);
    if (threads < 1) threads = 1;
    hits = malloc((size_t)width * height * 4);
    if (!hits) die("cannot allocate the hit buffer");
    tiles_x = (width + 7) / 8;
    tiles_y = (height + 7) / 8;
    pthread_t *tid = malloc(sizeof(pthread_t) * threads);
    double *ms = malloc(sizeof(double) * (runs + 1));
    // One warm-up frame, then the timed runs.
    for (unsigned r = 0; r <= runs; r++) {
        atomic_store(&next_tile, 0);
        double s = now();
        for (long t = 0; t < threads; t++) pthread_create(&tid[t], NULL, worker, NULL);
        for (long t = 0; t < threads; t++) pthread_join(tid[t], NULL);
        ms[r] = (now() - s) * 1e3;
    }
    qsort(ms + 1, runs, sizeof(double), cmp);
    double med = runs % 2 ? ms[1 + runs / 2] : (ms[runs / 2] + ms[runs / 2 + 1]) / 2.0;
    snprintf(path, sizeof path, "%s/hits.bin", argv[1]);
    f = fopen(path, "wb");
    if (!f || fwrite(hits, 4, (size_t)width * height, f) != (size_t)width * height) die("cannot write hits.bin");
    fclose(f);
    printf("{\"peer\":\"embree %d.%d.%d rtcIntersect8\",\"threads\":%ld,\"build_ms\":%.3f,"
           "\"trace_ms_median\":%.3f,\"trace_ms_min\":%.3f,\"trace_ms_max\":%.3f,\"mrays_per_s\":%.4f}\n",
           RTC_VERSION_MAJOR, RTC_VERSION_MINOR, RTC_VERSION_PATCH, threads, build_ms, med, ms[1],
           ms[runs], (double)width * height / (med * 1e-3) / 1e6);
    rtcReleaseScene(scene);
    rtcReleaseDevice(device);
    return 0;
}
