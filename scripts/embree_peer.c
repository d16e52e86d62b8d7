// The Embree peer of `dcrt bench rays --peer embree`: traces the same camera rays through the same
// triangles with Embree 3 on every core, and in AO and path modes secondary rays of the same
// kinds and counts as dcrt's, so that dcrt's rate can be set against it in one run.
//
// Input directory (written by dcrt):
//   mesh.bin    u32 triangle count n, then n x 9 f32 (v0, v1, v2), little-endian, input order
//   camera.txt  width height runs, then origin, forward, right, up (3 floats each), then the
//               mode: `cast`, `ao RAYS DISTANCE` or `path DEPTH SX SY SZ` (S: unit direction
//               towards the sun; all zero: no sun, no sun rays)
// Output: hits.bin (u32 primitive id per pixel, row-major, y down; 0xffffffff on a miss) and one
// JSON line on stdout: the rates count every ray traced in a frame (camera and secondary).
//
// A pixel's ray is d = normalize(forward + sx right + sy up) with sx = 2 (x + 0.5) / width - 1 and
// sy = 1 - 2 (y + 0.5) / height, in f32, as dcrt's raygen makes it. Each thread takes 8x8 tiles
// from a shared counter and traces them as eight rtcIntersect8 packets, one per tile row. AO:
// from each hit, RAYS cosine-weighted occlusion rays about the normal facing the camera, up to
// DISTANCE, as rtcOccluded8 packets of the row's pixels' k-th rays, which share a stratum as
// dcrt's patches' do. Path: DEPTH waves from each
// live vertex, a sun ray (rtcOccluded8, when the sun is above the surface) and a cosine-weighted
// bounce (rtcIntersect8), a path ending when its bounce misses (dcrt's bench plays no Russian
// roulette either: its depth is the bounce roulette starts at). Directions
// come from a hash of (pixel, ray, depth): the rays are dcrt's kinds and counts, not its bits.
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

enum mode { CAST, AO, PATH };

static unsigned width, height, runs;
static float org[3], fwd[3], right_[3], up[3];
static enum mode mode = CAST;
static unsigned ao_rays, max_depth;
static float ao_distance, sun[3];
static RTCScene scene;
static uint32_t *hits;
static atomic_uint next_tile;
static atomic_ullong rays_traced;
static unsigned tiles_x, tiles_y;

// lowbias32 (C. Wellons).
static uint32_t hash(uint32_t x) {
    x ^= x >> 16;
    x *= 0x7feb352du;
    x ^= x >> 15;
    x *= 0x846ca68bu;
    x ^= x >> 16;
    return x;
}

static float unit(uint32_t x) { return (float)(x >> 8) * (1.0f / 16777216.0f); }

// Cosine-weighted direction about unit n for (pixel, k), with Duff et al.'s basis. With a group
// other than NO_GROUP, the point in [0,1)^2 lies in one of 4x4 strata chosen by (group, k), as
// dcrt's AO rays of a 4x2 pixel patch share their k-th stratum: a packet's k-th AO rays leave
// as alike as a subgroup's in dcrt.
#define NO_GROUP 0xffffffffu
static void cosine_dir(const float n[3], uint32_t pixel, uint32_t group, uint32_t k, float out[3]) {
    uint32_t h = hash(pixel * 0x9e3779b9u ^ hash(k + 0x632be5abu));
    float u1 = unit(hash(h ^ 0x2c1b3c6du)), u2 = unit(hash(h ^ 0x297a2d39u));
    if (group != NO_GROUP) {
        uint32_t g = hash(group * 0x85ebca6bu ^ hash(k + 0x632be5abu));
        u1 = ((float)(g & 3u) + u1) * 0.25f;
        u2 = ((float)((g >> 2) & 3u) + u2) * 0.25f;
    }
    float s = n[2] >= 0.0f ? 1.0f : -1.0f;
    float a = -1.0f / (s + n[2]);
    float b = n[0] * n[1] * a;
    float t[3] = {1.0f + s * n[0] * n[0] * a, s * b, -s * n[0]};
    float bt[3] = {b, s + n[1] * n[1] * a, -n[1]};
    float r = sqrtf(u1), phi = 6.28318531f * u2;
    float c = r * cosf(phi), d = r * sinf(phi), z = sqrtf(fmaxf(0.0f, 1.0f - u1));
    for (int i = 0; i < 3; i++) out[i] = c * t[i] + d * bt[i] + z * n[i];
}

// Lane i's hit in rh: its point and unit normal facing the ray, the point moved off the surface
// by 1e-4 of its largest coordinate (the origin of the rays spawned there): coarse, far above
// the hit point's rounding so no ray meets its own triangle, where dcrt's offset is the error
// bound. It can only skip occluders closer than that, which makes the peer's work lighter.
static void spawn_point(const struct RTCRayHit8 *rh, unsigned i, float p[3], float n[3]) {
    float d[3] = {rh->ray.dir_x[i], rh->ray.dir_y[i], rh->ray.dir_z[i]};
    float o[3] = {rh->ray.org_x[i], rh->ray.org_y[i], rh->ray.org_z[i]};
    float g[3] = {rh->hit.Ng_x[i], rh->hit.Ng_y[i], rh->hit.Ng_z[i]};
    float l = sqrtf(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
    float f = (g[0] * d[0] + g[1] * d[1] + g[2] * d[2]) > 0.0f ? -1.0f : 1.0f;
    float m = 0.0f;
    for (int k = 0; k < 3; k++) {
        n[k] = f * g[k] / l;
        p[k] = o[k] + rh->ray.tfar[i] * d[k];
        m = fmaxf(m, fabsf(p[k]));
    }
    for (int k = 0; k < 3; k++) p[k] += n[k] * 1e-4f * (1.0f + m);
}

static void set_ray(struct RTCRay8 *r, unsigned i, const float o[3], const float d[3], float tfar) {
    r->org_x[i] = o[0];
    r->org_y[i] = o[1];
    r->org_z[i] = o[2];
    r->dir_x[i] = d[0];
    r->dir_y[i] = d[1];
    r->dir_z[i] = d[2];
    r->tnear[i] = 0.0f;
    r->tfar[i] = tfar;
    r->time[i] = 0.0f;
    r->mask[i] = -1;
    r->id[i] = i;
    r->flags[i] = 0;
}

static unsigned lanes(const int valid[8]) {
    unsigned n = 0;
    for (int i = 0; i < 8; i++) n += valid[i] != 0;
    return n;
}

// The secondary rays of one packet row whose camera rays are in rh (lane i: pixel px[i]).
static unsigned long long secondary(struct RTCIntersectContext *ctx, struct RTCRayHit8 *rh,
                                    const int valid[8], const uint32_t px[8]) {
    unsigned long long traced = 0;
    int live[8] __attribute__((aligned(32)));
    for (int i = 0; i < 8; i++)
        live[i] = valid[i] && rh->hit.geomID[i] != RTC_INVALID_GEOMETRY_ID ? -1 : 0;
    unsigned waves = mode == AO ? 1 : max_depth;
    for (unsigned w = 0; w < waves && lanes(live); w++) {
        float p[8][3], n[8][3];
        for (int i = 0; i < 8; i++)
            if (live[i]) spawn_point(rh, i, p[i], n[i]);
        if (mode == AO) {
            for (unsigned k = 0; k < ao_rays; k++) {
                struct RTCRay8 r __attribute__((aligned(32)));
                for (int i = 0; i < 8; i++) {
                    float d[3] = {0.0f, 0.0f, 1.0f};
                    if (live[i]) cosine_dir(n[i], px[i], px[0], k, d);
                    set_ray(&r, i, live[i] ? p[i] : org, d, ao_distance);
                }
                rtcOccluded8(live, scene, ctx, &r);
                traced += lanes(live);
            }
            break;
        }
        // Path: the sun ray, then the bounce, whose hits are the next wave's vertices.
        int lit[8] __attribute__((aligned(32)));
        struct RTCRay8 s __attribute__((aligned(32)));
        for (int i = 0; i < 8; i++) {
            lit[i] = live[i] && n[i][0] * sun[0] + n[i][1] * sun[1] + n[i][2] * sun[2] > 0.0f ? -1 : 0;
            set_ray(&s, i, live[i] ? p[i] : org, sun, INFINITY);
        }
        if (lanes(lit)) {
            rtcOccluded8(lit, scene, ctx, &s);
            traced += lanes(lit);
        }
        for (int i = 0; i < 8; i++) {
            float d[3] = {0.0f, 0.0f, 1.0f};
            if (live[i]) cosine_dir(n[i], px[i], NO_GROUP, 1000u + w, d);
            set_ray(&rh->ray, i, live[i] ? p[i] : org, d, INFINITY);
            rh->hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
            rh->hit.primID[i] = RTC_INVALID_GEOMETRY_ID;
        }
        rtcIntersect8(live, scene, ctx, rh);
        traced += lanes(live);
        for (int i = 0; i < 8; i++)
            if (live[i] && rh->hit.geomID[i] == RTC_INVALID_GEOMETRY_ID) live[i] = 0;
    }
    return traced;
}

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
    unsigned long long traced = 0;
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
            traced += lanes(valid);
            uint32_t px[8];
            for (unsigned i = 0; i < 8; i++) px[i] = y * width + x0 + i;
            for (unsigned i = 0; i < 8 && x0 + i < width; i++) {
                uint32_t id = rh.hit.geomID[i] == RTC_INVALID_GEOMETRY_ID ? 0xffffffffu : rh.hit.primID[i];
                hits[(size_t)y * width + x0 + i] = id;
            }
            if (mode != CAST) traced += secondary(&ctx, &rh, valid, px);
        }
    }
    atomic_fetch_add(&rays_traced, traced);
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
    char name[16];
    if (fscanf(f, "%15s", name) != 1) die("camera.txt: no mode after the vectors");
    if (strcmp(name, "cast") == 0) {
        mode = CAST;
    } else if (strcmp(name, "ao") == 0) {
        mode = AO;
        if (fscanf(f, "%u %f", &ao_rays, &ao_distance) != 2 || ao_rays == 0 || !(ao_distance > 0.0f))
            die("camera.txt: ao needs a ray count above 0 and a distance above 0");
    } else if (strcmp(name, "path") == 0) {
        mode = PATH;
        if (fscanf(f, "%u %f %f %f", &max_depth, &sun[0], &sun[1], &sun[2]) != 4 || max_depth == 0)
            die("camera.txt: path needs a depth above 0 and the sun's direction");
    } else {
        die("camera.txt: the mode is cast, ao or path");
    }
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
    unsigned long long rays = 0;
    for (unsigned r = 0; r <= runs; r++) {
        atomic_store(&next_tile, 0);
        atomic_store(&rays_traced, 0);
        double s = now();
        for (long t = 0; t < threads; t++) pthread_create(&tid[t], NULL, worker, NULL);
        for (long t = 0; t < threads; t++) pthread_join(tid[t], NULL);
        ms[r] = (now() - s) * 1e3;
        rays = atomic_load(&rays_traced);
    }
    qsort(ms + 1, runs, sizeof(double), cmp);
    double med = runs % 2 ? ms[1 + runs / 2] : (ms[runs / 2] + ms[runs / 2 + 1]) / 2.0;
    snprintf(path, sizeof path, "%s/hits.bin", argv[1]);
    f = fopen(path, "wb");
    if (!f || fwrite(hits, 4, (size_t)width * height, f) != (size_t)width * height) die("cannot write hits.bin");
    fclose(f);
    printf("{\"peer\":\"embree %d.%d.%d %s\",\"mode\":\"%s\",\"threads\":%ld,"
           "\"build_ms\":%.3f,\"trace_ms_median\":%.3f,\"trace_ms_min\":%.3f,\"trace_ms_max\":%.3f,"
           "\"rays\":%llu,\"mrays_per_s\":%.4f}\n",
           RTC_VERSION_MAJOR, RTC_VERSION_MINOR, RTC_VERSION_PATCH,
           mode == CAST ? "rtcIntersect8" : "rtcIntersect8+rtcOccluded8", name, threads, build_ms, med,
           ms[1], ms[runs], rays, (double)rays / (med * 1e-3) / 1e6);
    rtcReleaseScene(scene);
    rtcReleaseDevice(device);
    return 0;
}
