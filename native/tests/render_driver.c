/* A test program that runs the library's public API (include/splatcore.h) on scenes read from
 * files and writes every output, so the builds for other platforms (Windows under wine, arm64
 * Linux under qemu) can be compared bit for bit with this machine's. Linked with the same
 * objects as the platform's module (scripts/verify_native_platforms.py builds and runs it).
 *
 *   render_driver SCENE OUTPUT
 *
 * SCENE, little-endian: "SCN1", int32 n, k, sh_degree, width, height, antialiased, threads,
 * has_background, has_mesh; float64 world_to_camera[16], intrinsics[4] (fx fy cx cy), near;
 * float32 means[n,3], log_scales[n,3], quats[n,4], opacity_logits[n], sh[n,k,3],
 * background[3] if has_background, mesh_rgba[h,w,4] and mesh_depth[h,w] if has_mesh,
 * target[h,w,3] (the training target).
 * OUTPUT: float32 rgb, alpha, depth of sc_render; of sc_render_train (no mesh layer); the
 * L1+SSIM gradient against the target and float64 loss, l1, ssim; the sc_backward gradients
 * means, log_scales, quats, opacity_logits, sh, xy, xy_abs; the means after two sc_adam steps.
 * Exit status 0, or 1 with a message on stderr. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "splatcore.h"

static FILE *in_file, *out_file;

static void fail(const char *what) {
    fprintf(stderr, "render_driver: %s\n", what);
    exit(1);
}

static void *read_array(size_t count, size_t size) {
    void *p = calloc(count ? count : 1, size);
    if (!p) fail("out of memory");
    if (fread(p, size, count, in_file) != count) fail("scene file is truncated");
    return p;
}

static void *zeros(size_t count, size_t size) {
    void *p = calloc(count ? count : 1, size);
    if (!p) fail("out of memory");
    return p;
}

static void write_array(const void *p, size_t count, size_t size) {
    if (fwrite(p, size, count, out_file) != count) fail("cannot write the output file");
}

int main(int argc, char **argv) {
    if (argc != 3) fail("usage: render_driver SCENE OUTPUT");
    if (!(in_file = fopen(argv[1], "rb"))) fail("cannot open the scene file");
    char magic[4];
    if (fread(magic, 1, 4, in_file) != 4 || memcmp(magic, "SCN1", 4) != 0) fail("not a scene file");
    int32_t *h = read_array(9, sizeof(int32_t));
    const int64_t n = h[0];
    const int k = h[1], width = h[3], height = h[4];
    const size_t pixels = (size_t)width * (size_t)height;
    double *cam_values = read_array(21, sizeof(double));
    sc_camera cam = {.fx = cam_values[16], .fy = cam_values[17], .cx = cam_values[18],
                     .cy = cam_values[19], .width = width, .height = height};
    memcpy(cam.world_to_camera, cam_values, sizeof cam.world_to_camera);
    const sc_options opt = {.sh_degree = h[2], .near = cam_values[20], .antialiased = h[5],
                            .threads = h[6]};
    sc_gaussians g = {.count = n, .sh_coeffs = k};
    g.means = read_array((size_t)n * 3, 4);
    g.log_scales = read_array((size_t)n * 3, 4);
    g.quats = read_array((size_t)n * 4, 4);
    g.opacity_logits = read_array((size_t)n, 4);
    g.sh = read_array((size_t)n * k * 3, 4);
    sc_image image = {.rgb = zeros(pixels * 3, 4), .alpha = zeros(pixels, 4),
                      .depth = zeros(pixels, 4)};
    if (h[7]) image.background = read_array(3, 4);
    if (h[8]) {
        image.mesh_rgba = read_array(pixels * 4, 4);
        image.mesh_depth = read_array(pixels, 4);
    }
    float *target = read_array(pixels * 3, 4);
    fclose(in_file);
    if (!(out_file = fopen(argv[2], "wb"))) fail("cannot open the output file");

    fprintf(stderr, "render_driver: %d threads, %s kernels\n", opt.threads, sc_cpu_isa_name());
    sc_stats stats = {0};
    if (sc_render(&g, &cam, &opt, &image, &stats) != SC_OK) fail("sc_render failed");
    write_array(image.rgb, pixels * 3, 4);
    write_array(image.alpha, pixels, 4);
    write_array(image.depth, pixels, 4);

    image.mesh_rgba = NULL, image.mesh_depth = NULL;
    sc_train_state state = {0};
    if (sc_render_train(&g, &cam, &opt, &image, &state, &stats) != SC_OK)
        fail("sc_render_train failed");
    write_array(image.rgb, pixels * 3, 4);
    write_array(image.alpha, pixels, 4);
    write_array(image.depth, pixels, 4);

    float *d_rgb = zeros(pixels * 3, 4);
    double losses[3];
    if (sc_l1_ssim(image.rgb, target, width, height, 0.2, opt.threads, d_rgb, &losses[0],
                   &losses[1], &losses[2], NULL) != SC_OK)
        fail("sc_l1_ssim failed");
    write_array(d_rgb, pixels * 3, 4);
    write_array(losses, 3, sizeof(double));

    sc_gaussian_grads grads = {
        .means = zeros((size_t)n * 3, 4), .log_scales = zeros((size_t)n * 3, 4),
        .quats = zeros((size_t)n * 4, 4), .opacity_logits = zeros((size_t)n, 4),
        .sh = zeros((size_t)n * k * 3, 4), .xy = zeros((size_t)n * 2, 4),
        .xy_abs = zeros((size_t)n * 2, 4)};
    sc_backward_stats bstats = {0};
    if (sc_backward(&state, &g, d_rgb, NULL, NULL, opt.threads, &grads, &bstats) != SC_OK)
        fail("sc_backward failed");
    sc_train_state_free(&state);
    write_array(grads.means, (size_t)n * 3, 4);
    write_array(grads.log_scales, (size_t)n * 3, 4);
    write_array(grads.quats, (size_t)n * 4, 4);
    write_array(grads.opacity_logits, (size_t)n, 4);
    write_array(grads.sh, (size_t)n * k * 3, 4);
    write_array(grads.xy, (size_t)n * 2, 4);
    write_array(grads.xy_abs, (size_t)n * 2, 4);

    float *means = zeros((size_t)n * 3, 4), *m = zeros((size_t)n * 3, 4), *v = zeros((size_t)n * 3, 4);
    memcpy(means, g.means, sizeof(float) * (size_t)n * 3);
    for (int64_t step = 1; step <= 2; ++step) {
        const sc_adam_options adam = {.lr = 1.6e-4, .beta1 = 0.9, .beta2 = 0.999, .eps = 1e-15,
                                      .step = step};
        sc_adam(means, grads.means, m, v, n * 3, &adam, opt.threads);
    }
    write_array(means, (size_t)n * 3, 4);
    if (fclose(out_file) != 0) fail("cannot write the output file");
    return 0;
}
