// Tile compositing on the CPU: the same front-to-back blend as composite.py's torch backend
// (gsplat's rules), written as loops so no fragment tensor is ever materialised.
//
// Each tile is one unit of work (OpenMP over tiles). Inside a tile the Gaussians are the outer
// loop, front to back, and the tile's pixels the inner one, eight floats (four doubles) at a
// time in GCC/Clang vector types: every pixel keeps its own transmittance and stops on its own,
// and the tile stops when all of its pixels have. The backward walks each tile's Gaussians back
// to front from the final transmittance, dividing alpha back out (as gsplat's kernel does), and
// adds each Gaussian's gradients into its thread's own row, summed by the caller; tiles go to
// threads in a fixed order, so a run repeats bit for bit with the same number of threads.
//
// Built on first use by liquidgs/render/cpu_backend.py and called through ctypes: plain C
// types only, no torch headers, so it compiles in about a second with g++ or clang++.

#if !defined(LIQUIDGS_MAX_ALPHA) || !defined(LIQUIDGS_ALPHA_THRESHOLD) || !defined(LIQUIDGS_MIN_TRANSMITTANCE) || \
    !defined(LIQUIDGS_MAX_EXTENT_SIGMAS) || !defined(LIQUIDGS_FRUSTUM_MARGIN) || !defined(LIQUIDGS_MAX_EXTRA_FEATURES)
#error "built by liquidgs/render/cpu_backend.py, which passes the constants of the torch backend (DEFINES)"
#endif

#include <cmath>
#include <cstdint>
#include <vector>
#ifdef _OPENMP
#include <omp.h>
#endif

namespace {

constexpr int kMaxTileSize = 32;
// RGB and depth, then the caller's extra feature channels (up to LIQUIDGS_MAX_EXTRA_FEATURES): the
// kernels are compiled for each count, so the loops over features unroll.
constexpr int kMinFeatures = 4;
constexpr int kMaxFeatures = kMinFeatures + static_cast<int>(LIQUIDGS_MAX_EXTRA_FEATURES);
// Gradient row per Gaussian: means2d (2), conics (3), opacity (1), |means2d| (2), then the features.
constexpr int kRowHead = 8;

// 32-byte vectors of pixels and the integer masks their comparisons give.
struct F32 {
    using S = float;
    using I = int32_t;
    typedef float V __attribute__((vector_size(32)));
    typedef int32_t M __attribute__((vector_size(32)));
    static constexpr int lanes = 8;
};
struct F64 {
    using S = double;
    using I = int64_t;
    typedef double V __attribute__((vector_size(32)));
    typedef int64_t M __attribute__((vector_size(32)));
    static constexpr int lanes = 4;
};

template <typename P> struct Limits {
    using S = typename P::S;
    static constexpr S max_alpha = S(LIQUIDGS_MAX_ALPHA);
    static constexpr S alpha_threshold = S(LIQUIDGS_ALPHA_THRESHOLD);
    static constexpr S min_transmittance = S(LIQUIDGS_MIN_TRANSMITTANCE);
};

template <typename P> inline typename P::V splat(typename P::S value) {
    return typename P::V{} + value;
}

// exp(x) for x <= 0, eight lanes at once: 2^n * p(r) with Cephes' expf polynomial (about
// 1 ulp). glibc's vector exp would need -ffast-math, which would also reorder the sums.
inline F32::V exp_neg(F32::V x) {
    using V = F32::V;
    using M = F32::M;
    x = x > splat<F32>(-87.0f) ? x : splat<F32>(-87.0f);
    const V t = x * 1.44269504088896341f + 0.5f;
    M n = __builtin_convertvector(t, M);  // truncates towards zero; floor for t < 0:
    n += (__builtin_convertvector(n, V) > t);  // a true comparison is -1
    const V nf = __builtin_convertvector(n, V);
    const V r = (x - nf * 0.693359375f) + nf * 2.12194440e-4f;
    V p = splat<F32>(1.9875691500e-4f);
    p = p * r + 1.3981999507e-3f;
    p = p * r + 8.3334519073e-3f;
    p = p * r + 4.1665795894e-2f;
    p = p * r + 1.6666665459e-1f;
    p = p * r + 5.0000001201e-1f;
    p = p * r * r + r + 1.0f;
    return p * reinterpret_cast<V>((n + 127) << 23);
}
// Doubles are the reference precision of the tests, not a fast path: libm's exp per lane.
inline F64::V exp_neg(F64::V x) {
    F64::V out;
    for (int lane = 0; lane < F64::lanes; ++lane) out[lane] = std::exp(x[lane]);
    return out;
}

// The lanes summed as a tree (halves added, then their halves): three vector additions for eight
// lanes where a chain takes seven dependent scalar ones.
template <typename P> typename P::S lane_sum(typename P::V v) {
    typename P::S half[P::lanes];
    for (int lane = 0; lane < P::lanes; ++lane) half[lane] = v[lane];
    for (int width = P::lanes / 2; width >= 1; width /= 2)
        for (int lane = 0; lane < width; ++lane) half[lane] += half[lane + width];
    return half[0];
}

struct TileGeometry {
    int tile_size, tiles_x, width, height;
    int pixels() const { return tile_size * tile_size; }
    int64_t image_index(int64_t tile, int p) const {
        const int x = static_cast<int>(tile % tiles_x) * tile_size + p % tile_size;
        const int y = static_cast<int>(tile / tiles_x) * tile_size + p / tile_size;
        return x < width && y < height ? static_cast<int64_t>(y) * width + x : -1;
    }
};

// Pixel centres of one tile, lane by lane, and the mask of those inside the image.
template <typename P>
void tile_pixels(const TileGeometry& g, int64_t tile, typename P::V* px, typename P::V* py, typename P::M* inside) {
    for (int p = 0; p < g.pixels(); ++p) {
        const int j = p / P::lanes, lane = p % P::lanes;
        px[j][lane] = static_cast<typename P::S>(static_cast<int>(tile % g.tiles_x) * g.tile_size + p % g.tile_size) + 0.5;
        py[j][lane] = static_cast<typename P::S>(static_cast<int>(tile / g.tiles_x) * g.tile_size + p / g.tile_size) + 0.5;
        inside[j][lane] = g.image_index(tile, p) >= 0 ? -1 : 0;
    }
}

template <typename P, int kFeatures> struct Gaussian2D {
    using S = typename P::S;
    S mx, my, ca, cb, cc, opacity, feature[kFeatures];
    Gaussian2D(const S* means2d, const S* conics, const S* opacities, const S* features, int64_t id)
        : mx(means2d[2 * id]), my(means2d[2 * id + 1]), ca(conics[3 * id]), cb(conics[3 * id + 1]),
          cc(conics[3 * id + 2]), opacity(opacities[id]) {
        for (int f = 0; f < kFeatures; ++f) feature[f] = features[id * kFeatures + f];
    }
};

template <typename P, int kFeatures>
void forward(const typename P::S* means2d, const typename P::S* conics, const typename P::S* opacities,
             const typename P::S* features, const int64_t* gaussian_ids, const int64_t* tile_starts,
             const int64_t* tile_counts, const int64_t* tile_order, int64_t n_tiles, TileGeometry g,
             typename P::S* out_features, typename P::S* out_transmittance, int32_t* out_last) {
    using S = typename P::S;
    using V = typename P::V;
    using M = typename P::M;
    using L = Limits<P>;
    constexpr int kMaxVectors = kMaxTileSize * kMaxTileSize / P::lanes;
#pragma omp parallel for schedule(dynamic, 1)
    for (int64_t i = 0; i < n_tiles; ++i) {
        const int64_t tile = tile_order[i];
        const int vectors = g.pixels() / P::lanes;
        V px[kMaxVectors], py[kMaxVectors], T[kMaxVectors], acc[kFeatures][kMaxVectors];
        M last[kMaxVectors], active[kMaxVectors];
        tile_pixels<P>(g, tile, px, py, active);
        for (int j = 0; j < vectors; ++j) {
            T[j] = splat<P>(1);
            last[j] = M{} - 1;
            for (int f = 0; f < kFeatures; ++f) acc[f][j] = V{};
        }
        const int64_t start = tile_starts[tile], count = tile_counts[tile];
        for (int64_t k = 0; k < count; ++k) {
            const Gaussian2D<P, kFeatures> gs(means2d, conics, opacities, features, gaussian_ids[start + k]);
            M any_active = M{};
            for (int j = 0; j < vectors; ++j) {
                const V dx = gs.mx - px[j], dy = gs.my - py[j];
                const V sigma = S(0.5) * (gs.ca * dx * dx + gs.cc * dy * dy) + gs.cb * dx * dy;
                const V gauss_alpha = gs.opacity * exp_neg(-sigma);
                const V alpha = gauss_alpha < L::max_alpha ? gauss_alpha : splat<P>(L::max_alpha);
                const M kept = active[j] & (sigma >= S(0)) & (alpha >= L::alpha_threshold);
                const V next_T = T[j] * (S(1) - alpha);
                const M stops = kept & (next_T <= L::min_transmittance);
                const M composited = kept & ~stops;
                const V weight = composited ? alpha * T[j] : V{};
                for (int f = 0; f < kFeatures; ++f) acc[f][j] += weight * gs.feature[f];
                T[j] = composited ? next_T : T[j];
                last[j] = composited ? M{} + static_cast<typename P::I>(k) : last[j];
                active[j] &= ~stops;
                any_active |= active[j];
            }
            bool done = true;
            for (int lane = 0; lane < P::lanes; ++lane) done = done && any_active[lane] == 0;
            if (done) break;
        }
        for (int p = 0; p < g.pixels(); ++p) {
            const int64_t pixel = g.image_index(tile, p);
            if (pixel < 0) continue;
            const int j = p / P::lanes, lane = p % P::lanes;
            for (int f = 0; f < kFeatures; ++f) out_features[pixel * kFeatures + f] = acc[f][j][lane];
            out_transmittance[pixel] = T[j][lane];
            out_last[pixel] = static_cast<int32_t>(last[j][lane]);
        }
    }
}

template <typename P, int kFeatures>
void backward(const typename P::S* means2d, const typename P::S* conics, const typename P::S* opacities,
              const typename P::S* features, const int64_t* gaussian_ids, const int64_t* tile_starts,
              const int64_t* tile_counts, const int64_t* tile_order, int64_t n_tiles, TileGeometry g,
              const typename P::S* transmittance, const int32_t* last_index, const typename P::S* grad_features,
              const typename P::S* grad_alpha, int64_t n_gaussians, int slices, typename P::S* slice_grads) {
    using S = typename P::S;
    using V = typename P::V;
    using M = typename P::M;
    using L = Limits<P>;
    constexpr int kMaxVectors = kMaxTileSize * kMaxTileSize / P::lanes;
    (void)tile_order;
    (void)n_tiles;
    // The image's tiles, in raster order, are cut into a fixed number of bands (slices), each
    // with its own sums and its tiles taken in order; the slices are then added in order. The
    // threads only share out the slices, so the gradients are the same bits for any thread
    // count; a band touches mostly its own Gaussians, so its sums stay in cache.
    constexpr int kRow = kRowHead + kFeatures;
    const int64_t row_values = n_gaussians * kRow;
    const int64_t all_tiles = static_cast<int64_t>(g.tiles_x) * ((g.height + g.tile_size - 1) / g.tile_size);
#pragma omp parallel for schedule(dynamic, 1)
    for (int slice = 0; slice < slices; ++slice)
    for (int64_t tile = all_tiles * slice / slices; tile < all_tiles * (slice + 1) / slices; ++tile) {
        if (tile_counts[tile] == 0) continue;
        const int vectors = g.pixels() / P::lanes;
        S* grads = slice_grads + slice * row_values;
        V px[kMaxVectors], py[kMaxVectors], T[kMaxVectors], T_final[kMaxVectors], behind[kMaxVectors];
        V g_alpha[kMaxVectors], g_out[kFeatures][kMaxVectors];
        M last[kMaxVectors], inside[kMaxVectors];
        tile_pixels<P>(g, tile, px, py, inside);
        int64_t deepest = -1;
        for (int p = 0; p < g.pixels(); ++p) {
            const int64_t pixel = g.image_index(tile, p);
            const int j = p / P::lanes, lane = p % P::lanes;
            // Pixels outside the image: transmittance 1, nothing composited, no gradient.
            T[j][lane] = T_final[j][lane] = pixel < 0 ? S(1) : transmittance[pixel];
            last[j][lane] = pixel < 0 ? -1 : last_index[pixel];
            g_alpha[j][lane] = pixel < 0 ? S(0) : grad_alpha[pixel];
            for (int f = 0; f < kFeatures; ++f) g_out[f][j][lane] = pixel < 0 ? S(0) : grad_features[pixel * kFeatures + f];
            behind[j][lane] = 0;
            deepest = last[j][lane] > deepest ? last[j][lane] : deepest;
        }
        const int64_t start = tile_starts[tile];
        for (int64_t k = deepest; k >= 0; --k) {
            const int64_t id = gaussian_ids[start + k];
            const Gaussian2D<P, kFeatures> gs(means2d, conics, opacities, features, id);
            V gx{}, gy{}, abs_gx{}, abs_gy{}, g_ca{}, g_cb{}, g_cc{}, g_opacity{}, g_feature[kFeatures] = {};
            for (int j = 0; j < vectors; ++j) {
                const V dx = gs.mx - px[j], dy = gs.my - py[j];
                const V sigma = S(0.5) * (gs.ca * dx * dx + gs.cc * dy * dy) + gs.cb * dx * dy;
                const V falloff = exp_neg(-sigma);
                const V gauss_alpha = gs.opacity * falloff;
                const V alpha = gauss_alpha < L::max_alpha ? gauss_alpha : splat<P>(L::max_alpha);
                // Up to a pixel's last composited fragment, every kept fragment was composited.
                const M composited = (last[j] >= static_cast<typename P::I>(k)) & (sigma >= S(0)) &
                                     (alpha >= L::alpha_threshold);
                const V one_minus = S(1) - (composited ? alpha : V{});
                const V T_before = T[j] / one_minus;
                const V weight = composited ? alpha * T_before : V{};
                V feature_dot = V{};
                for (int f = 0; f < kFeatures; ++f) feature_dot += gs.feature[f] * g_out[f][j];
                const V d_alpha = T_before * feature_dot - behind[j] / one_minus + g_alpha[j] * T_final[j] / one_minus;
                const V d_alpha_kept = (composited & (gauss_alpha <= L::max_alpha)) ? d_alpha : V{};
                const V d_sigma = -d_alpha_kept * gauss_alpha;
                const V px_grad = d_sigma * (gs.ca * dx + gs.cb * dy);
                const V py_grad = d_sigma * (gs.cb * dx + gs.cc * dy);
                gx += px_grad;
                gy += py_grad;
                abs_gx += px_grad < S(0) ? -px_grad : px_grad;
                abs_gy += py_grad < S(0) ? -py_grad : py_grad;
                g_ca += S(0.5) * d_sigma * dx * dx;
                g_cb += d_sigma * dx * dy;
                g_cc += S(0.5) * d_sigma * dy * dy;
                g_opacity += d_alpha_kept * falloff;
                for (int f = 0; f < kFeatures; ++f) g_feature[f] += weight * g_out[f][j];
                behind[j] += weight * feature_dot;
                T[j] = T_before;
            }
            S* out = grads + id * kRow;
            out[0] += lane_sum<P>(gx);
            out[1] += lane_sum<P>(gy);
            out[2] += lane_sum<P>(g_ca);
            out[3] += lane_sum<P>(g_cb);
            out[4] += lane_sum<P>(g_cc);
            out[5] += lane_sum<P>(g_opacity);
            out[6] += lane_sum<P>(abs_gx);
            out[7] += lane_sum<P>(abs_gy);
            for (int f = 0; f < kFeatures; ++f) out[kRowHead + f] += lane_sum<P>(g_feature[f]);
        }
    }
    // The total into the first slice.
#pragma omp parallel for schedule(static)
    for (int64_t v = 0; v < row_values; ++v) {
        S total = slice_grads[v];
        for (int slice = 1; slice < slices; ++slice) total += slice_grads[slice * row_values + v];
        slice_grads[v] = total;
    }
}

// Counting sort of (tile, Gaussian) pairs by tile; Gaussians arrive front to back, so each
// tile's list stays in depth order without a comparison sort.
void bin_tiles(const int64_t* depth_order, const int64_t* tile_box, int64_t n_visible, int tiles_x,
               int64_t n_tiles, int64_t* tile_starts, int64_t* tile_counts, int64_t* gaussian_ids) {
    for (int64_t t = 0; t < n_tiles; ++t) tile_counts[t] = 0;
    for (int64_t v = 0; v < n_visible; ++v) {
        const int64_t* box = tile_box + 4 * v;  // x_min, y_min, x_max, y_max (exclusive)
        for (int64_t y = box[1]; y < box[3]; ++y)
            for (int64_t x = box[0]; x < box[2]; ++x) ++tile_counts[y * tiles_x + x];
    }
    int64_t offset = 0;
    for (int64_t t = 0; t < n_tiles; ++t) {
        tile_starts[t] = offset;
        offset += tile_counts[t];
    }
    std::vector<int64_t> next(tile_starts, tile_starts + n_tiles);
    for (int64_t v = 0; v < n_visible; ++v) {
        const int64_t* box = tile_box + 4 * v;
        for (int64_t y = box[1]; y < box[3]; ++y)
            for (int64_t x = box[0]; x < box[2]; ++x) gaussian_ids[next[y * tiles_x + x]++] = depth_order[v];
    }
}

void set_threads(int threads) {
#ifdef _OPENMP
    omp_set_num_threads(threads);
#else
    (void)threads;
#endif
}

// forward / backward compiled for `features` channels, kMinFeatures..kMaxFeatures (cpu_backend.py
// checks the count; any other does nothing).
template <typename P, int kFeatures = kMinFeatures, typename... Args> void forward_for(int features, Args... args) {
    if constexpr (kFeatures <= kMaxFeatures) {
        if (features == kFeatures) return forward<P, kFeatures>(args...);
        forward_for<P, kFeatures + 1>(features, args...);
    }
}
template <typename P, int kFeatures = kMinFeatures, typename... Args> void backward_for(int features, Args... args) {
    if constexpr (kFeatures <= kMaxFeatures) {
        if (features == kFeatures) return backward<P, kFeatures>(args...);
        backward_for<P, kFeatures + 1>(features, args...);
    }
}

}  // namespace

extern "C" {

int liquidgs_max_features() { return kMaxFeatures; }

int liquidgs_max_tile_size() { return kMaxTileSize; }

void liquidgs_bin_tiles(const int64_t* depth_order, const int64_t* tile_box, int64_t n_visible, int tiles_x,
                        int64_t n_tiles, int64_t* tile_starts, int64_t* tile_counts, int64_t* gaussian_ids) {
    bin_tiles(depth_order, tile_box, n_visible, tiles_x, n_tiles, tile_starts, tile_counts, gaussian_ids);
}

#define LIQUIDGS_EXPORT(P, suffix)                                                                                  \
    void liquidgs_composite_forward_##suffix(                                                                       \
        const P::S* means2d, const P::S* conics, const P::S* opacities, const P::S* features,                     \
        const int64_t* gaussian_ids, const int64_t* tile_starts, const int64_t* tile_counts,                      \
        const int64_t* tile_order, int64_t n_tiles, int tile_size, int tiles_x, int width, int height,           \
        int features_count, P::S* out_features, P::S* out_transmittance, int32_t* out_last, int threads) {       \
        set_threads(threads);                                                                                       \
        forward_for<P>(features_count, means2d, conics, opacities, features, gaussian_ids, tile_starts,            \
                       tile_counts, tile_order, n_tiles, TileGeometry{tile_size, tiles_x, width, height},           \
                       out_features, out_transmittance, out_last);                                                 \
    }                                                                                                               \
    void liquidgs_composite_backward_##suffix(                                                                      \
        const P::S* means2d, const P::S* conics, const P::S* opacities, const P::S* features,                     \
        const int64_t* gaussian_ids, const int64_t* tile_starts, const int64_t* tile_counts,                      \
        const int64_t* tile_order, int64_t n_tiles, int tile_size, int tiles_x, int width, int height,           \
        int features_count, const P::S* transmittance, const int32_t* last_index, const P::S* grad_features,     \
        const P::S* grad_alpha, int64_t n_gaussians, int slices, P::S* slice_grads, int threads) {                \
        set_threads(threads);                                                                                       \
        backward_for<P>(features_count, means2d, conics, opacities, features, gaussian_ids, tile_starts,           \
                        tile_counts, tile_order, n_tiles, TileGeometry{tile_size, tiles_x, width, height},          \
                        transmittance, last_index, grad_features, grad_alpha, n_gaussians, slices, slice_grads);    \
    }

LIQUIDGS_EXPORT(F32, f32)
LIQUIDGS_EXPORT(F64, f64)
}
