// The GPU marching loop's kernels: nerf_bundle._gpu (CuPy) and nerf-render --device cuda
// (runtime/src/gpu) compile this file with NVRTC, without fused multiply-adds, after
// `#define SEGMENT <MARCH_SEGMENT>`. The float32 arithmetic is the CPU loops' own
// (core/src/render/grid.rs and compositing.rs; nerf_bundle/_render.py), operation for
// operation, so the samples and pixels are theirs.
// The padded grid's cell of a point, as Grid.occupied_along: u = (v + b) / (2b) · R per axis,
// NaN and below 0 to the padding at -1, R and above to the padding at R.
__device__ __forceinline__ bool occupied(const unsigned char* padded, int side, float b, float two_b, float rf,
                                         float x, float y, float z) {
    float p[3] = {x, y, z};
    int c[3];
    for (int a = 0; a < 3; ++a) {
        float u = ((p[a] + b) / two_b) * rf;
        u = fminf(fmaxf(u, -1.0f), rf);  // fmaxf(NaN, -1) = -1
        c[a] = (int)floorf(u) + 1;
    }
    return padded[((long long)c[0] * side + c[1]) * side + c[2]] != 0;
}

extern "C" __global__ void march(const int* active, int m, const float* o, const float* d, int* cursor, int steps,
                                 float near, float interval, const unsigned char* padded, int side, float b, float two_b,
                                 float rf, int* ks, int* counts) {
    int i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= m) return;
    int r = active[i];
    float ox = o[3 * r], oy = o[3 * r + 1], oz = o[3 * r + 2];
    float dx = d[3 * r], dy = d[3 * r + 1], dz = d[3 * r + 2];
    int k = cursor[r], n = 0;
    while (k < steps && n < SEGMENT) {
        float t = near + ((float)k + 0.5f) * interval;
        if (occupied(padded, side, b, two_b, rf, t * dx + ox, t * dy + oy, t * dz + oz)) {
            ks[i * SEGMENT + n] = k;
            ++n;
        }
        ++k;
    }
    cursor[r] = k;
    counts[i] = n;
}

// The field's inputs: ray by ray, each ray's samples in order from its offset.
extern "C" __global__ void emit(const int* active, int m, const int* ks, const int* counts, const long long* offsets,
                                const float* o, const float* d, const float* viewdirs, float near, float interval,
                                float* points, float* dirs, float* ts) {
    int i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= m) return;
    int r = active[i];
    long long at = offsets[i];
    for (int j = 0; j < counts[i]; ++j, ++at) {
        float t = near + ((float)ks[i * SEGMENT + j] + 0.5f) * interval;
        for (int a = 0; a < 3; ++a) {
            points[3 * at + a] = t * d[3 * r + a] + o[3 * r + a];
            dirs[3 * at + a] = viewdirs[3 * r + a];
        }
        ts[at] = t;
    }
}

// RayAccumulator::add over each ray's samples, in order; keep[i]: the ray goes on.
extern "C" __global__ void composite(const int* active, int m, const int* counts, const long long* offsets,
                                     const float* sigma, const float* colour, const float* ts, const float* delta,
                                     float* trans, float* rgb, float* depth, float* acc, float min_t, bool* keep) {
    int i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= m) return;
    int r = active[i];
    float tr = trans[r], cr = rgb[3 * r], cg = rgb[3 * r + 1], cb = rgb[3 * r + 2], de = depth[r], ac = acc[r];
    long long at = offsets[i];
    for (int j = 0; j < counts[i]; ++j, ++at) {
        float s = sigma[at];
        float x = isnan(s) ? s : fmaxf(s, 0.0f);  // np.maximum keeps NaN
        x = -(x * delta[r]);
        float alpha = 1.0f - (float)exp((double)x);
        float w = alpha * tr;
        cr = cr + w * colour[3 * at];
        cg = cg + w * colour[3 * at + 1];
        cb = cb + w * colour[3 * at + 2];
        de = de + w * ts[at];
        ac = ac + w;
        tr = tr * ((1.0f - alpha) + 1e-10f);
    }
    trans[r] = tr;
    rgb[3 * r] = cr;
    rgb[3 * r + 1] = cg;
    rgb[3 * r + 2] = cb;
    depth[r] = de;
    acc[r] = ac;
    keep[i] = tr >= min_t && counts[i] == SEGMENT;
}
