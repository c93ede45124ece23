// The CfC cell's gate on the CPU, forward and backward, fused: from the cell's four heads
// [ff1 | ff2 | time_a | time_b] (one [N, 4H] row per Gaussian), the elapsed time tau and an
// optional noise offset on time_b's output,
//
//     h' = tanh(ff1) * (1 - s) + tanh(ff2) * s,   s = sigmoid(time_a * tau + (time_b + offset)).
//
// In torch this is a dozen elementwise passes each way over column slices (which torch's
// vectorised tanh does not take), about 5 ms per cell and step at 5k Gaussians on a 2-core
// CPU; here it is one pass each way. The backward recomputes the forward from the heads and
// writes the heads' gradient as one [N, 4H] block, which is what the heads' matrix product
// needs. float32 runs eight lanes at a time with Cephes' expf polynomial (about 1 ulp) and
// Cephes' tanhf, for H a multiple of 8 (cpu_gate.py sends other widths to torch); float64
// (the tests' precision) uses the C library's exp and tanh.
//
// Built on first use by liquidgs/fields/cpu_gate.py through liquidgs.native; called through
// ctypes, plain C types only.

#include <cmath>
#include <cstdint>
#include <cstring>

namespace {

typedef float V8 __attribute__((vector_size(32)));
typedef int32_t I8 __attribute__((vector_size(32)));
constexpr int kLanes = 8;

inline V8 splat(float value) { return V8{} + value; }

inline V8 vmin(V8 a, V8 b) { return a < b ? a : b; }
inline V8 vmax(V8 a, V8 b) { return a > b ? a : b; }

// exp(x), eight lanes: 2^n p(r) with Cephes' expf polynomial; inputs clamped to +-88.
inline V8 vexp(V8 x) {
    x = vmin(vmax(x, splat(-88.0f)), splat(88.0f));
    V8 n = x * 1.44269504088896341f + 0.5f;
    // floor: truncate, then step down where truncation went up (negative non-integers).
    V8 truncated = __builtin_convertvector(__builtin_convertvector(n, I8), V8);
    n = truncated > n ? truncated - 1.0f : truncated;
    const V8 r = x - n * 0.693359375f + n * 2.12194440e-4f;
    V8 p = splat(1.9875691500e-4f);
    p = p * r + 1.3981999507e-3f;
    p = p * r + 8.3334519073e-3f;
    p = p * r + 4.1665795894e-2f;
    p = p * r + 1.6666665459e-1f;
    p = p * r + 5.0000001201e-1f;
    p = p * (r * r) + r + 1.0f;
    const I8 bits = (__builtin_convertvector(n, I8) + 127) << 23;
    V8 scale;
    std::memcpy(&scale, &bits, sizeof(scale));
    return p * scale;
}

inline V8 vsigmoid(V8 x) { return 1.0f / (1.0f + vexp(-x)); }

// tanh(x), eight lanes: Cephes' tanhf (an odd polynomial below 0.625, 1 - 2 / (e^2|x| + 1) above).
inline V8 vtanh(V8 x) {
    const V8 ax = x < 0 ? -x : x;
    const V8 z = x * x;
    V8 small = splat(-5.70498872745e-3f);
    small = small * z + 2.06390887954e-2f;
    small = small * z - 5.37397155531e-2f;
    small = small * z + 1.33314422036e-1f;
    small = small * z - 3.33332819422e-1f;
    small = small * z * x + x;
    V8 large = 1.0f - 2.0f / (vexp(2.0f * ax) + 1.0f);
    large = x < 0 ? -large : large;
    return ax < 0.625f ? small : large;
}

inline V8 load(const float* p) {
    V8 v;
    std::memcpy(&v, p, sizeof(v));
    return v;
}
inline void store(float* p, V8 v) { std::memcpy(p, &v, sizeof(v)); }

// One Gaussian's row, columns [start, start + 8) of each head. float32.
inline void forward_lanes(const float* row, int hidden, int start, float tau, const float* offset, float* out) {
    const V8 a = vtanh(load(row + start));
    const V8 c = vtanh(load(row + hidden + start));
    V8 time_b = load(row + 3 * hidden + start);
    if (offset) time_b = time_b + load(offset + start);
    const V8 s = vsigmoid(load(row + 2 * hidden + start) * tau + time_b);
    store(out + start, a * (1.0f - s) + s * c);
}

// Returns this block's share of d tau.
inline float backward_lanes(const float* row, int hidden, int start, float tau, const float* offset,
                            const float* grad_out, float* grad_row, float* grad_offset) {
    const V8 a = vtanh(load(row + start));
    const V8 c = vtanh(load(row + hidden + start));
    const V8 time_a = load(row + 2 * hidden + start);
    V8 time_b = load(row + 3 * hidden + start);
    if (offset) time_b = time_b + load(offset + start);
    const V8 s = vsigmoid(time_a * tau + time_b);
    const V8 g = load(grad_out + start);
    const V8 g_logit = g * (c - a) * (s * (1.0f - s));
    store(grad_row + start, g * (1.0f - s) * (1.0f - a * a));
    store(grad_row + hidden + start, g * s * (1.0f - c * c));
    store(grad_row + 2 * hidden + start, g_logit * tau);
    store(grad_row + 3 * hidden + start, g_logit);
    if (grad_offset) store(grad_offset + start, g_logit);
    const V8 share = g_logit * time_a;
    float sum = 0;
    for (int lane = 0; lane < kLanes; ++lane) sum += share[lane];
    return sum;
}

// The same, one value at a time in float64.
inline void forward_one(const double* row, int hidden, int k, double tau, const double* offset, double* out) {
    const double a = std::tanh(row[k]), c = std::tanh(row[hidden + k]);
    const double time_b = offset ? row[3 * hidden + k] + offset[k] : row[3 * hidden + k];
    const double s = 1.0 / (1.0 + std::exp(-(row[2 * hidden + k] * tau + time_b)));
    out[k] = a * (1.0 - s) + s * c;
}

inline double backward_one(const double* row, int hidden, int k, double tau, const double* offset,
                           const double* grad_out, double* grad_row, double* grad_offset) {
    const double a = std::tanh(row[k]), c = std::tanh(row[hidden + k]);
    const double time_a = row[2 * hidden + k];
    const double time_b = offset ? row[3 * hidden + k] + offset[k] : row[3 * hidden + k];
    const double s = 1.0 / (1.0 + std::exp(-(time_a * tau + time_b)));
    const double g = grad_out[k];
    const double g_logit = g * (c - a) * (s * (1.0 - s));
    grad_row[k] = g * (1.0 - s) * (1.0 - a * a);
    grad_row[hidden + k] = g * s * (1.0 - c * c);
    grad_row[2 * hidden + k] = g_logit * tau;
    grad_row[3 * hidden + k] = g_logit;
    if (grad_offset) grad_offset[k] = g_logit;
    return g_logit * time_a;
}

inline void forward_row(const float* row, int hidden, float tau, const float* offset, float* out) {
    for (int k = 0; k < hidden; k += kLanes) forward_lanes(row, hidden, k, tau, offset, out);
}
inline void forward_row(const double* row, int hidden, double tau, const double* offset, double* out) {
    for (int k = 0; k < hidden; ++k) forward_one(row, hidden, k, tau, offset, out);
}
inline float backward_row(const float* row, int hidden, float tau, const float* offset, const float* grad_out,
                          float* grad_row, float* grad_offset) {
    float sum = 0;
    for (int k = 0; k < hidden; k += kLanes)
        sum += backward_lanes(row, hidden, k, tau, offset, grad_out, grad_row, grad_offset);
    return sum;
}
inline double backward_row(const double* row, int hidden, double tau, const double* offset,
                           const double* grad_out, double* grad_row, double* grad_offset) {
    double sum = 0;
    for (int k = 0; k < hidden; ++k) sum += backward_one(row, hidden, k, tau, offset, grad_out, grad_row, grad_offset);
    return sum;
}

// tau is read at tau[i * tau_stride] (stride 0: one time for every Gaussian); offset may be null.
template <typename S>
void gate_forward(const S* heads, int64_t n, int hidden, const S* tau, int64_t tau_stride, const S* offset, S* out,
                  int threads) {
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int64_t i = 0; i < n; ++i)
        forward_row(heads + i * 4 * hidden, hidden, tau[i * tau_stride], offset ? offset + i * hidden : nullptr,
                    out + i * hidden);
}

// grad_tau ([n], per Gaussian) and grad_offset may be null when not wanted.
template <typename S>
void gate_backward(const S* heads, int64_t n, int hidden, const S* tau, int64_t tau_stride, const S* offset,
                   const S* grad_out, S* grad_heads, S* grad_tau, S* grad_offset, int threads) {
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int64_t i = 0; i < n; ++i) {
        const S share = backward_row(heads + i * 4 * hidden, hidden, tau[i * tau_stride],
                                     offset ? offset + i * hidden : nullptr, grad_out + i * hidden,
                                     grad_heads + i * 4 * hidden, grad_offset ? grad_offset + i * hidden : nullptr);
        if (grad_tau) grad_tau[i] = share;
    }
}

}  // namespace

#define LIQUIDGS_GATE_EXPORTS(S, SUFFIX)                                                                         \
    extern "C" void liquidgs_cfc_gate_forward_##SUFFIX(const S* heads, int64_t n, int hidden, const S* tau,      \
                                                       int64_t tau_stride, const S* offset, S* out, int threads) { \
        gate_forward<S>(heads, n, hidden, tau, tau_stride, offset, out, threads);                                \
    }                                                                                                            \
    extern "C" void liquidgs_cfc_gate_backward_##SUFFIX(const S* heads, int64_t n, int hidden, const S* tau,     \
                                                        int64_t tau_stride, const S* offset, const S* grad_out,  \
                                                        S* grad_heads, S* grad_tau, S* grad_offset, int threads) { \
        gate_backward<S>(heads, n, hidden, tau, tau_stride, offset, grad_out, grad_heads, grad_tau, grad_offset,  \
                         threads);                                                                               \
    }

LIQUIDGS_GATE_EXPORTS(float, f32)
LIQUIDGS_GATE_EXPORTS(double, f64)
