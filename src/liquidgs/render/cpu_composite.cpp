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
    !defined(LIQUIDGS_MAX_EXTENT_SIGMAS) || !defined(LIQUIDGS_FRUSTUM_MARGIN) || !defined(LIQUIDGS_MAX_EXTRA_FEATURES) || \
    !defined(LIQUIDGS_FOOTPRINT_MARGIN)
#error "built by liquidgs/render/cpu_backend.py, which passes the constants of the torch backend (DEFINES)"
#endif

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
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

// tiles.py's footprint_columns, in the same order of operations and without fused multiply-adds
// (torch rounds each operation), so both keep the same tiles: the tile columns [first, last] of a
// tile row holding a pixel centre where a Gaussian's alpha can reach the threshold (-inf, inf
// where the conic is not positive definite). What does not depend on the row is found once.
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC push_options
#pragma GCC optimize("fp-contract=off")
#endif
struct Footprint {
    double mx, my, b, inverse_a, reach_sq, det, reach_v, extreme_v;
    bool positive;
    template <typename S> Footprint(const S* mean, const S* conic, S opacity) : mx(mean[0]), my(mean[1]), b(conic[1]) {
        const double a = conic[0], c = conic[2];
        const double cut = std::max(std::log(double(opacity) / double(LIQUIDGS_ALPHA_THRESHOLD)), 0.0) +
                           double(LIQUIDGS_FOOTPRINT_MARGIN);
        inverse_a = 1.0 / a;
        reach_sq = 2.0 * cut * a;
        det = a * c - b * b;
        reach_v = std::sqrt(reach_sq / det);
        extreme_v = -b * std::sqrt(2.0 * cut / (det * c));
        positive = a > 0 && c > 0 && det > 0;
    }
    double half_width(double v) const { return std::sqrt(std::max(reach_sq - det * v * v, 0.0)); }
    void columns(int64_t row, int tile_size, double inverse_tile, double* first, double* last) const {
        const double band_low = double(row) * tile_size + 0.5 - my;
        const double band_high = band_low + (tile_size - 1);
        const double low = std::max(band_low, -reach_v), high = std::min(band_high, reach_v);
        const double right_v = std::min(std::max(extreme_v, low), high);
        const double left_v = std::min(std::max(-extreme_v, low), high);
        const double right = mx + (-b * right_v + half_width(right_v)) * inverse_a;
        const double left = mx + (-b * left_v - half_width(left_v)) * inverse_a;
        *first = std::ceil((left + 0.5) * inverse_tile - 1.0);
        *last = low <= high ? std::floor((right - 0.5) * inverse_tile) : *first - 1;
        if (!(positive && std::isfinite(*first) && std::isfinite(*last))) *first = -INFINITY, *last = INFINITY;
    }
};

// The unsigned integer of a float's width, and a float's bits as one that orders as the float does
// (negative floats reversed below the positive ones; -0 taken as +0, which torch's sort ties with it).
template <typename S> struct OrderedBits;
template <> struct OrderedBits<float> {
    using U = uint32_t;
};
template <> struct OrderedBits<double> {
    using U = uint64_t;
};
template <typename S> typename OrderedBits<S>::U ordered_bits(S value) {
    using U = typename OrderedBits<S>::U;
    constexpr U sign = U(1) << (8 * sizeof(U) - 1);
    U bits;
    const S zeroed = value == S(0) ? S(0) : value;
    std::memcpy(&bits, &zeroed, sizeof bits);
    return bits & sign ? ~bits : bits | sign;
}

// tiles.py's tile_boxes: the visible Gaussians (radii_xy x > 0) front to back - a stable radix
// sort of the depths, so equal depths keep the lower id first as torch's stable argsort does - and
// the tiles [x0, x1) x [y0, y1) their box touches, with torch's operations in S: centre and radius
// divided by the tile size, floor / ceil, clamped to the image's tiles.
template <typename S>
void tile_boxes(const S* means2d, const int32_t* radii_xy, const S* depths, int64_t n, int tile_size, int64_t tiles_x,
                int64_t tiles_y, std::vector<int64_t>& order, std::vector<int64_t>& boxes) {
    using U = typename OrderedBits<S>::U;
    std::vector<U> keys, sorted_keys;
    order.clear();
    for (int64_t i = 0; i < n; ++i)
        if (radii_xy[2 * i] > 0) {
            order.push_back(i);
            keys.push_back(ordered_bits(depths[i]));
        }
    const size_t visible = order.size();
    std::vector<int64_t> sorted(visible);
    sorted_keys.resize(visible);
    for (int shift = 0; shift < int(8 * sizeof(U)); shift += 8) {
        size_t starts[257] = {};
        for (size_t i = 0; i < visible; ++i) ++starts[((keys[i] >> shift) & 255) + 1];
        if (*std::max_element(starts + 1, starts + 257) == visible) continue;  // one digit: nothing moves
        for (int digit = 0; digit < 256; ++digit) starts[digit + 1] += starts[digit];
        for (size_t i = 0; i < visible; ++i) {
            const size_t to = starts[(keys[i] >> shift) & 255]++;
            sorted[to] = order[i];
            sorted_keys[to] = keys[i];
        }
        order.swap(sorted);
        keys.swap(sorted_keys);
    }
    boxes.resize(4 * visible);
    const auto clamped = [](S value, int64_t upper) {
        return value < S(0) ? int64_t(0) : value > S(upper) ? upper : int64_t(value);
    };
    for (size_t v = 0; v < visible; ++v) {
        const int64_t id = order[v];
        const S cx = means2d[2 * id] / S(tile_size), cy = means2d[2 * id + 1] / S(tile_size);
        const S rx = S(radii_xy[2 * id]) / S(tile_size), ry = S(radii_xy[2 * id + 1]) / S(tile_size);
        boxes[4 * v] = clamped(std::floor(cx - rx), tiles_x);
        boxes[4 * v + 1] = clamped(std::floor(cy - ry), tiles_y);
        boxes[4 * v + 2] = clamped(std::ceil(cx + rx), tiles_x);
        boxes[4 * v + 3] = clamped(std::ceil(cy + ry), tiles_y);
    }
}

// tiles.py's bin_gaussians: each visible Gaussian in the tiles of its box that footprint_columns
// keeps, the pairs counting-sorted by tile (the Gaussians arrive front to back, so each tile's list
// stays in depth order without a comparison sort). Returns the number of pairs; where it is over
// `capacity` (the caller's bound on them), gaussian_ids is left unwritten.
template <typename S>
int64_t bin_gaussians(const S* means2d, const S* conics, const S* opacities, const int32_t* radii_xy,
                      const S* depths, int64_t n, int tile_size, int64_t tiles_x, int64_t tiles_y, int64_t capacity,
                      int64_t* tile_starts, int64_t* tile_counts, int64_t* gaussian_ids) {
    std::vector<int64_t> order, boxes;
    tile_boxes(means2d, radii_xy, depths, n, tile_size, tiles_x, tiles_y, order, boxes);
    const int64_t visible = int64_t(order.size()), n_tiles = tiles_x * tiles_y;
    // Each Gaussian's columns [x0, x1) per row of its box, found once for the count and the fill.
    std::vector<int64_t> first_row(visible + 1, 0);
    for (int64_t v = 0; v < visible; ++v) first_row[v + 1] = first_row[v] + boxes[4 * v + 3] - boxes[4 * v + 1];
    std::vector<int64_t> columns(2 * first_row[visible]);
    const double inverse_tile = 1.0 / tile_size;
    // The columns first, the counts after: rows without a branch on the columns overlap.
    for (int64_t v = 0; v < visible; ++v) {
        const int64_t* box = boxes.data() + 4 * v;  // x_min, y_min, x_max, y_max (exclusive)
        const int64_t id = order[v];
        const Footprint footprint(means2d + 2 * id, conics + 3 * id, opacities[id]);
        for (int64_t y = box[1]; y < box[3]; ++y) {
            double first, last;
            footprint.columns(y, tile_size, inverse_tile, &first, &last);
            int64_t* row = columns.data() + 2 * (first_row[v] + y - box[1]);
            row[0] = first > double(box[0]) ? int64_t(first) : box[0];
            row[1] = last + 1 < double(box[2]) ? int64_t(last) + 1 : box[2];
        }
    }
    for (int64_t t = 0; t < n_tiles; ++t) tile_counts[t] = 0;
    for (int64_t v = 0; v < visible; ++v) {
        const int64_t* box = boxes.data() + 4 * v;
        for (int64_t y = box[1]; y < box[3]; ++y) {
            const int64_t* row = columns.data() + 2 * (first_row[v] + y - box[1]);
            for (int64_t x = row[0]; x < row[1]; ++x) ++tile_counts[y * tiles_x + x];
        }
    }
    int64_t offset = 0;
    for (int64_t t = 0; t < n_tiles; ++t) {
        tile_starts[t] = offset;
        offset += tile_counts[t];
    }
    if (offset > capacity) return offset;
    std::vector<int64_t> next(tile_starts, tile_starts + n_tiles);
    for (int64_t v = 0; v < visible; ++v) {
        const int64_t* box = boxes.data() + 4 * v;
        for (int64_t y = box[1]; y < box[3]; ++y) {
            const int64_t* row = columns.data() + 2 * (first_row[v] + y - box[1]);
            for (int64_t x = row[0]; x < row[1]; ++x) gaussian_ids[next[y * tiles_x + x]++] = order[v];
        }
    }
    return offset;
}
#if defined(__clang__)
#pragma clang fp contract(on)
#elif defined(__GNUC__)
#pragma GCC pop_options
#endif

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


#define LIQUIDGS_EXPORT(P, suffix)                                                                                  \
    int64_t liquidgs_bin_gaussians_##suffix(                                                                        \
        const P::S* means2d, const P::S* conics, const P::S* opacities, const int32_t* radii_xy, const P::S* depths, \
        int64_t n, int tile_size, int64_t tiles_x, int64_t tiles_y, int64_t capacity, int64_t* tile_starts,        \
        int64_t* tile_counts, int64_t* gaussian_ids) {                                                              \
        return bin_gaussians(means2d, conics, opacities, radii_xy, depths, n, tile_size, tiles_x, tiles_y, capacity, \
                             tile_starts, tile_counts, gaussian_ids);                                               \
    }                                                                                                               \
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
