// SSIM of one image pair on the CPU, forward and backward, as eval/metrics.py's torch ssim
// computes it: the five local statistics (mu_x, mu_y, E[x^2], E[y^2], E[xy]) by a zero-padded
// "same" separable Gaussian filter of each channel, the SSIM map from them, its mean.
//
// Images are [H, W, C], channels last and contiguous, so a row is W * C values and a step of
// one pixel along it is C values: the horizontal filter runs along the whole interleaved row
// with taps C apart, the vertical one adds up whole rows. Every loop over a row is a plain loop
// over contiguous values that the compiler vectorises (no -ffast-math: each sum keeps its order).
//
// Forward: the image is cut into bands of rows, one per thread. A band walks down its rows
// keeping the last 11 horizontally filtered rows of the five statistics in a ring (so they stay
// in cache; a band's first rows also filter the 5 rows above it, the only repeated work); for
// each row, the vertical filter of the ring gives the statistics, then the SSIM map and its row
// sum and - when a gradient is wanted - the map's partial derivatives with respect to mu_x,
// E[x^2] and E[xy], already filtered horizontally. The filter is its own adjoint (symmetric
// window, zero padding), so the backward is one more pass: the vertical filter of those three
// saved planes, combined as dS/dx = f(d mu_x) + 2 x f(d E[x^2]) + y f(d E[xy]).
//
// Every row's values are computed by the same operations in the same order whichever band
// holds it, and the score is the sum of the row sums in row order: results repeat bit for bit
// on every run and for any number of threads.
//
// Built on first use by liquidgs/eval/cpu_ssim.py and called through ctypes: plain C types
// only, no torch headers.

#include <algorithm>
#include <cstdint>
#include <memory>

namespace {

constexpr int kRadius = 5;
constexpr int kTaps = 2 * kRadius + 1;
constexpr int kStats = 5;         // mu_x, mu_y, E[x^2], E[y^2], E[xy]
constexpr int kPartials = 3;      // dS/dmu_x, dS/dE[x^2], dS/dE[xy]
constexpr int kLanes = 8;         // interleaved partial sums of a row's map (vectorised, fixed order)
constexpr int64_t kMinBand = 16;  // rows per band at least: a band repeats 5 rows' horizontal work

struct Geometry {
    int64_t height, row;  // row = W * C values
    int channels;
    int64_t pad() const { return kRadius * channels; }
    int64_t padded() const { return row + 2 * pad(); }
    int64_t plane() const { return height * row; }
    int bands(int threads) const {
        return static_cast<int>(std::max<int64_t>(1, std::min<int64_t>(threads, height / kMinBand)));
    }
    int64_t band_start(int band, int bands) const { return height * band / bands; }
};

// out[i] = sum_k w[k] in[i + (k - R) C] for a row padded with R pixels of zeros on each side.
// The taps are the inner loop (unrolled, summed in a register), the row the vectorised one.
template <typename S> void filter_row(const S* padded, const S* w, const Geometry& g, S* __restrict out) {
    const int64_t c = g.channels;
    S wk[kTaps];
    for (int k = 0; k < kTaps; ++k) wk[k] = w[k];
    for (int64_t i = 0; i < g.row; ++i) {
        S sum = wk[0] * padded[i];
        for (int k = 1; k < kTaps; ++k) sum += wk[k] * padded[i + k * c];
        out[i] = sum;
    }
}

// out[i] = sum_k w[k] rows[k][i]: the vertical filter, rows outside the image being zero rows.
template <typename S> void filter_column(const S* const* rows, const S* w, int64_t row, S* __restrict out) {
    S wk[kTaps];
    for (int k = 0; k < kTaps; ++k) wk[k] = w[k];
    for (int64_t i = 0; i < row; ++i) {
        S sum = wk[0] * rows[0][i];
        for (int k = 1; k < kTaps; ++k) sum += wk[k] * rows[k][i];
        out[i] = sum;
    }
}

// The map's values along one row from the five statistics; with kGrad, its partial derivatives
// too. S = a1 a2 / (b1 b2) with a1, b1 functions of mu_x and a2, b2 of the sigmas.
template <bool kGrad, typename S>
void map_row(const S* __restrict stats, int64_t row, S c1, S c2, S* __restrict map, S* __restrict d_mu,
             S* __restrict d_xx, S* __restrict d_xy) {
    const S* mu_x = stats;
    const S* mu_y = mu_x + row;
    const S* e_xx = mu_y + row;
    const S* e_yy = e_xx + row;
    const S* e_xy = e_yy + row;
    for (int64_t i = 0; i < row; ++i) {
        const S mx = mu_x[i], my = mu_y[i];
        const S mu_xx = mx * mx, mu_yy = my * my, mu_xy = mx * my;
        const S a1 = S(2) * mu_xy + c1;
        const S a2 = S(2) * (e_xy[i] - mu_xy) + c2;
        const S b1 = mu_xx + mu_yy + c1;
        const S b2 = (e_xx[i] - mu_xx) + (e_yy[i] - mu_yy) + c2;
        const S den = b1 * b2;
        const S value = a1 * a2 / den;  // a division, as torch's: identical images give 1 exactly
        map[i] = value;
        if (kGrad) {
            const S d = S(1) / den;
            d_mu[i] = S(2) * (my * (a2 - a1) + mx * value * (b1 - b2)) * d;
            d_xx[i] = -value * b1 * d;
            d_xy[i] = S(2) * a1 * d;
        }
    }
}

// The sum of a row in double, in kLanes interleaved partial sums (a fixed order).
template <typename S> double row_sum(const S* values, int64_t row) {
    double lanes[kLanes] = {};
    const int64_t whole = row - row % kLanes;
    for (int64_t i = 0; i < whole; i += kLanes)
        for (int l = 0; l < kLanes; ++l) lanes[l] += static_cast<double>(values[i + l]);
    for (int64_t i = whole; i < row; ++i) lanes[i - whole] += static_cast<double>(values[i]);
    double sum = 0;
    for (int l = 0; l < kLanes; ++l) sum += lanes[l];
    return sum;
}

// One band's rows [first, last): their map sums into row_sums and, with partials, their
// filtered partial derivatives.
template <typename S>
void forward_band(const S* x, const S* y, const S* w, S c1, S c2, const Geometry& g, int64_t first, int64_t last,
                  S* partials, double* row_sums) {
    const int64_t row = g.row, padded = g.padded(), pad = g.pad();
    // Zero-padded rows (the pads stay zero), the ring of filtered rows, a zero row, the
    // statistics and the map of the current row.
    std::unique_ptr<S[]> scratch(new S[kStats * padded + kTaps * kStats * row + row + (kStats + 1) * row]());
    S* px[kStats];
    for (int s = 0; s < kStats; ++s) px[s] = scratch.get() + s * padded + pad;
    S* ring = scratch.get() + kStats * padded;
    const S* zeros = ring + kTaps * kStats * row;
    S* stats = ring + kTaps * kStats * row + row;
    S* map = stats + kStats * row;
    auto slot = [&](int64_t source, int s) { return ring + ((source % kTaps) * kStats + s) * row; };

    auto filter_source_row = [&](int64_t source) {
        const S* xr = x + source * row;
        const S* yr = y + source * row;
        for (int64_t i = 0; i < row; ++i) {
            px[0][i] = xr[i];
            px[1][i] = yr[i];
            px[2][i] = xr[i] * xr[i];
            px[3][i] = yr[i] * yr[i];
            px[4][i] = xr[i] * yr[i];
        }
        for (int s = 0; s < kStats; ++s) filter_row(px[s] - pad, w, g, slot(source, s));
    };
    for (int64_t source = std::max<int64_t>(0, first - kRadius); source < std::min(g.height, first + kRadius);
         ++source)
        filter_source_row(source);

    const S* rows[kTaps];
    for (int64_t r = first; r < last; ++r) {
        if (r + kRadius < g.height) filter_source_row(r + kRadius);
        for (int s = 0; s < kStats; ++s) {
            for (int k = 0; k < kTaps; ++k) {
                const int64_t source = r + k - kRadius;
                rows[k] = source >= 0 && source < g.height ? slot(source, s) : zeros;
            }
            filter_column(rows, w, row, stats + s * row);
        }
        if (partials == nullptr) {
            map_row<false>(stats, row, c1, c2, map, px[0], px[1], px[2]);
        } else {
            // The partials go into the padded rows (free until the next row), then through the
            // horizontal filter.
            map_row<true>(stats, row, c1, c2, map, px[0], px[1], px[2]);
            for (int s = 0; s < kPartials; ++s) filter_row(px[s] - pad, w, g, partials + s * g.plane() + r * row);
        }
        row_sums[r] = row_sum(map, row);
    }
}

// The score's sum over the image; with `partials` non-null, the three filtered partial maps.
template <typename S>
double forward(const S* x, const S* y, const S* w, S c1, S c2, const Geometry& g, S* partials, int threads) {
    std::unique_ptr<double[]> row_sums(new double[g.height]);
    const int bands = g.bands(threads);
#pragma omp parallel for num_threads(bands) schedule(static, 1)
    for (int band = 0; band < bands; ++band)
        forward_band(x, y, w, c1, c2, g, g.band_start(band, bands), g.band_start(band + 1, bands), partials,
                     row_sums.get());
    double total = 0;
    for (int64_t r = 0; r < g.height; ++r) total += row_sums[r];
    return total;
}

// grad = scale * (f(d mu_x) + 2 x f(d E[x^2]) + y f(d E[xy])), the partials already filtered
// horizontally by the forward.
template <typename S>
void backward(const S* x, const S* y, const S* w, const Geometry& g, const S* partials, S scale, S* grad,
              int threads) {
    const int64_t plane = g.plane(), row = g.row;
    std::unique_ptr<S[]> zeros(new S[row]());
    const int bands = g.bands(threads);
#pragma omp parallel num_threads(bands)
    {
        std::unique_ptr<S[]> sums(new S[kPartials * row]);
        const S* rows[kTaps];
#pragma omp for schedule(static)
        for (int64_t r = 0; r < g.height; ++r) {
            for (int s = 0; s < kPartials; ++s) {
                for (int k = 0; k < kTaps; ++k) {
                    const int64_t source = r + k - kRadius;
                    rows[k] = source >= 0 && source < g.height ? partials + s * plane + source * row : zeros.get();
                }
                filter_column(rows, w, row, sums.get() + s * row);
            }
            const S* f_mu = sums.get();
            const S* f_xx = f_mu + row;
            const S* f_xy = f_xx + row;
            const S* xr = x + r * row;
            const S* yr = y + r * row;
            S* out = grad + r * row;
            for (int64_t i = 0; i < row; ++i) out[i] = scale * (f_mu[i] + S(2) * xr[i] * f_xx[i] + yr[i] * f_xy[i]);
        }
    }
}

}  // namespace

extern "C" {

#define LIQUIDGS_EXPORT(S, suffix)                                                                                 \
    double liquidgs_ssim_forward_##suffix(const S* x, const S* y, const S* window, double c1, double c2,          \
                                          int64_t height, int64_t width, int channels, S* partials, int threads) { \
        return forward<S>(x, y, window, static_cast<S>(c1), static_cast<S>(c2),                                    \
                          Geometry{height, width * channels, channels}, partials, threads);                        \
    }                                                                                                              \
    void liquidgs_ssim_backward_##suffix(const S* x, const S* y, const S* window, int64_t height, int64_t width,   \
                                         int channels, const S* partials, double scale, S* grad, int threads) {    \
        backward<S>(x, y, window, Geometry{height, width * channels, channels}, partials, static_cast<S>(scale),   \
                    grad, threads);                                                                                \
    }

LIQUIDGS_EXPORT(float, f32)
LIQUIDGS_EXPORT(double, f64)
}
