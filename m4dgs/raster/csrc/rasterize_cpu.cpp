// Tile-based alpha compositing of projected 2D Gaussians on the CPU (OpenMP over tiles), forward and backward.
//
// Conventions (gsplat's): pixel centres at (x + 0.5, y + 0.5); sigma = 0.5 (a dx^2 + c dy^2) + b dx dy with
// (a, b, c) the conic and d = mean - pixel; alpha = min(0.999, opacity exp(-sigma)); contributions with
// alpha < 1/255 are skipped; a pixel stops (exclusive) when the next transmittance would be <= 1e-4.
// Inside a tile the loops are Gaussian-major (each Gaussian visits only the pixel rows/spans of its alpha >= 1/255
// ellipse), which keeps per-pixel depth order. The forward stores the final transmittance and, per pixel, the
// number of tile-list entries up to its last contributor; the backward walks back to front from there,
// recovering T by division (as gsplat does).
// Gradients are written per intersection (each belongs to exactly one tile, so no races) and then summed per
// Gaussian in list order, which keeps the result deterministic.

#ifndef M4DGS_KERNELS_ONLY  // defined only by stand-alone micro-benchmarks of the kernels
#include <torch/extension.h>
#endif

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <type_traits>
#include <vector>

#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#define M4DGS_SPAN8 1
#else
#define M4DGS_SPAN8 0
#endif

namespace {

template <typename T>
struct Consts {
    static constexpr T alpha_min = T(1) / T(255);
    static constexpr T alpha_max = T(0.999);
    static constexpr T t_min = T(1e-4);
};

// Channels are padded to a multiple of LANES in tile-local buffers so the per-channel loops vectorise without
// remainders (the padding holds zeros and is never written out).
constexpr int64_t LANES = 4;
// Span buffers are padded by SPAN8 entries: the AVX2 span loops read and write whole 8-pixel chunks.
constexpr int64_t SPAN8 = 8;
inline int64_t padded(int64_t C) { return (C + LANES - 1) / LANES * LANES; }

// Gathered, tile-local copy of the Gaussians of one tile (front to back).
template <typename T>
struct TileData {
    std::vector<T> mx, my, ca, cb, cc, op, thr, hy, feat;
    int64_t Cp = 0;
    void load(const int32_t *ids, int64_t n, const T *means2d, const T *conics, const T *opac, const T *features,
              int64_t C) {
        Cp = padded(C);
        mx.resize(n); my.resize(n); ca.resize(n); cb.resize(n); cc.resize(n); op.resize(n); thr.resize(n);
        hy.resize(n);
        feat.assign(n * Cp, T(0));
        for (int64_t k = 0; k < n; ++k) {
            const int64_t g = ids[k];
            mx[k] = means2d[2 * g];
            my[k] = means2d[2 * g + 1];
            ca[k] = conics[3 * g];
            cb[k] = conics[3 * g + 1];
            cc[k] = conics[3 * g + 2];
            op[k] = opac[g];
            // opacity * exp(-sigma) < 1/255 for sure when sigma > log(255 opacity) + 1e-3; the pixels visited per
            // Gaussian are those inside this (slightly enlarged) ellipse, and the exact gsplat test is still
            // made for each of them, so the margin only has to exceed rounding.
            thr[k] = std::log(std::max(op[k], T(1e-30)) * T(255)) + T(1e-3);
            // half height of the ellipse sigma <= thr: sqrt(2 thr cov11), cov11 = a / det(conic)
            const T det = ca[k] * cc[k] - cb[k] * cb[k];
            hy[k] = (thr[k] > T(0) && det > T(0) && ca[k] > T(0)) ? std::sqrt(T(2) * thr[k] * ca[k] / det) : T(-1);
            std::copy(features + g * C, features + (g + 1) * C, feat.begin() + k * Cp);
        }
    }
};

// floor(v) / ceil(v) clamped to [lo, hi] (NaN -> lo); integer arithmetic, as floorf/ceilf are library calls
// on baseline x86-64.
template <typename T>
inline int64_t floor_clamped(T v, int64_t lo, int64_t hi) {
    if (!(v >= T(lo))) return lo;
    if (v >= T(hi)) return hi;
    int64_t i = int64_t(v);
    return T(i) > v ? i - 1 : i;
}

template <typename T>
inline int64_t ceil_clamped(T v, int64_t lo, int64_t hi) {
    if (!(v > T(lo))) return lo;
    if (v > T(hi)) return hi;
    int64_t i = int64_t(v);
    return T(i) < v ? i + 1 : i;
}

// Rows [r_lo, r_hi] of the tile [y0, y1) met by the ellipse of Gaussian k (empty when r_lo > r_hi).
template <typename T>
inline void row_range(const TileData<T> &td, int64_t k, int64_t y0, int64_t y1, int64_t &r_lo, int64_t &r_hi) {
    r_lo = ceil_clamped(td.my[k] - td.hy[k] - T(0.5), y0, y1);
    r_hi = floor_clamped(td.my[k] + td.hy[k] - T(0.5), y0 - 1, y1 - 1);
}

// Pixel span [x_lo, x_hi] (tile-clipped, inclusive) of row py inside the ellipse of Gaussian k; false if empty.
template <typename T>
inline bool row_span(const TileData<T> &td, int64_t k, T dy, int64_t x0, int64_t x1, int64_t &x_lo,
                     int64_t &x_hi) {
    // 0.5 a dx^2 + b dy dx + 0.5 c dy^2 - thr <= 0, with dx = mx - (px + 0.5)
    const T a = td.ca[k], bdy = td.cb[k] * dy;
    const T disc = bdy * bdy - a * (td.cc[k] * dy * dy - T(2) * td.thr[k]);
    if (!(disc >= T(0))) return false;
    const T r = std::sqrt(disc);
    const T dx_lo = (-bdy - r) / a, dx_hi = (-bdy + r) / a;
    // px + 0.5 in [mx - dx_hi, mx - dx_lo] (thr carries a margin, so rounding here cannot drop a contributor)
    x_lo = ceil_clamped(td.mx[k] - dx_hi - T(0.5), x0, x1);
    x_hi = floor_clamped(td.mx[k] - dx_lo - T(0.5), x0 - 1, x1 - 1);
    return x_lo <= x_hi;
}

// exp(-s) for s >= 0. float: Cody-Waite reduction s = n ln2 + r, r in [0, ln2), and a degree-6 polynomial
// (about 2e-7 relative error, like the GPU's __expf), written without branches or calls so span loops vectorise.
// double: std::exp (used for gradcheck).
template <typename T>
inline T exp_neg(T s) {
    return std::exp(-s);
}

template <>
inline float exp_neg<float>(float s) {
    s = std::min(std::max(s, 0.0f), 80.0f);
    const int32_t n = int32_t(s * 1.44269504f);  // trunc == floor for s >= 0
    const float nf = float(n);
    const float r = (s - nf * 0.693145751953125f) - nf * 1.42860682e-6f;
    float p = 9.863136092e-04f;
    p = p * r - 7.973091924e-03f;
    p = p * r + 4.150174091e-02f;
    p = p * r - 1.666274102e-01f;
    p = p * r + 4.999955219e-01f;
    p = p * r - 9.999998077e-01f;
    p = p * r + 9.999999986e-01f;
    const int32_t bits = (127 - n) << 23;  // 2^-n
    float scale;
    std::memcpy(&scale, &bits, sizeof scale);
    return p * scale;
}

#if M4DGS_SPAN8
// AVX2 versions of the span loops' per-pixel arithmetic for float, 8 pixels at a time. Spans are short (a few
// pixels: the Gaussians of a trained scene are small), so the compiler's vector loop rarely ran and its scalar
// remainder did the work; these take every span in whole chunks, masking the lanes past its end. The formulas
// are exp_neg<float> and the scalar loops' (same constants, same order), and the forward and the backward both
// use span_alpha8, so the backward retraces exactly the forward's decisions.
inline __m256 exp_neg8(__m256 s) {
    s = _mm256_min_ps(_mm256_max_ps(s, _mm256_setzero_ps()), _mm256_set1_ps(80.0f));
    const __m256i n = _mm256_cvttps_epi32(_mm256_mul_ps(s, _mm256_set1_ps(1.44269504f)));
    const __m256 nf = _mm256_cvtepi32_ps(n);
    const __m256 r = _mm256_fnmadd_ps(nf, _mm256_set1_ps(1.42860682e-6f),
                                      _mm256_fnmadd_ps(nf, _mm256_set1_ps(0.693145751953125f), s));
    __m256 p = _mm256_set1_ps(9.863136092e-04f);
    p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(-7.973091924e-03f));
    p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(4.150174091e-02f));
    p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(-1.666274102e-01f));
    p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(4.999955219e-01f));
    p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(-9.999998077e-01f));
    p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(9.999999986e-01f));
    const __m256i bits = _mm256_slli_epi32(_mm256_sub_epi32(_mm256_set1_epi32(127), n), 23);  // 2^-n
    return _mm256_mul_ps(p, _mm256_castsi256_ps(bits));
}

// sigma, opacity * exp(-sigma) (raw) and alpha of the pixels dx = dxs, dxs - 1, ..., dxs - 7 of one row, and the
// lanes that pass the span tests (inside the first `rem` pixels, 0 <= sigma <= thr, alpha >= 1/255).
struct Span8 {
    __m256 sigma, vis, raw, alpha, ok;
};

inline Span8 span_alpha8(float ca, float bdy, float cdy, float op, float thr, float dxs, int64_t rem) {
    const __m256 iota = _mm256_setr_ps(0.f, 1.f, 2.f, 3.f, 4.f, 5.f, 6.f, 7.f);
    const __m256 dx = _mm256_sub_ps(_mm256_set1_ps(dxs), iota);
    Span8 o;
    // 0.5 a dx^2 + b dy dx + 0.5 c dy^2, as (0.5 a dx + b dy) dx + 0.5 c dy^2
    o.sigma = _mm256_fmadd_ps(_mm256_fmadd_ps(_mm256_set1_ps(0.5f * ca), dx, _mm256_set1_ps(bdy)), dx,
                              _mm256_set1_ps(cdy));
    o.vis = exp_neg8(o.sigma);
    o.raw = _mm256_mul_ps(_mm256_set1_ps(op), o.vis);
    o.alpha = _mm256_min_ps(_mm256_set1_ps(Consts<float>::alpha_max), o.raw);
    const __m256 in_span = _mm256_cmp_ps(iota, _mm256_set1_ps(float(rem)), _CMP_LT_OQ);
    o.ok = _mm256_and_ps(
        _mm256_and_ps(in_span, _mm256_cmp_ps(o.sigma, _mm256_setzero_ps(), _CMP_GE_OQ)),
        _mm256_and_ps(_mm256_cmp_ps(o.sigma, _mm256_set1_ps(thr), _CMP_LE_OQ),
                      _mm256_cmp_ps(o.alpha, _mm256_set1_ps(Consts<float>::alpha_min), _CMP_GE_OQ)));
    return o;
}

inline __m256i loadi8(const int32_t *p) { return _mm256_loadu_si256(reinterpret_cast<const __m256i *>(p)); }
inline void storei8(int32_t *p, __m256i v) { _mm256_storeu_si256(reinterpret_cast<__m256i *>(p), v); }
inline __m256i blendi8(__m256i a, __m256i b, __m256 mask) {
    return _mm256_castps_si256(_mm256_blendv_ps(_mm256_castsi256_ps(a), _mm256_castsi256_ps(b), mask));
}
#endif

template <typename T, int NB = 0>  // NB > 0: padded channel count NB * LANES known at compile time
void forward_kernel(const T *means2d, const T *conics, const T *opac, const T *features, int64_t C,
                    const int32_t *offsets, const int32_t *ids, int64_t W, int64_t H, int64_t ts,
                    int64_t tiles_x, int64_t tiles_y, int n_threads, T *out_feat, T *out_T, int32_t *out_last) {
    const int64_t n_tiles = tiles_x * tiles_y;
    const int64_t P = ts * ts, Cp = NB > 0 ? int64_t(NB) * LANES : padded(C);
#pragma omp parallel num_threads(n_threads)
    {
        TileData<T> td;
        std::vector<T> acc_v(P * Cp), Tr_v(P + SPAN8), w_v(ts + SPAN8);
        std::vector<int32_t> last_v(P + SPAN8), done_v(P + SPAN8);
        T *acc = acc_v.data(), *Tr = Tr_v.data(), *wv = w_v.data();
        int32_t *last = last_v.data(), *done = done_v.data();
#pragma omp for schedule(dynamic, 1)
        for (int64_t t = 0; t < n_tiles; ++t) {
            const int64_t s = offsets[t], n = offsets[t + 1] - s;
            const int64_t tx = t % tiles_x, ty = t / tiles_x;
            const int64_t x0 = tx * ts, y0 = ty * ts;
            const int64_t x1 = std::min(W, x0 + ts), y1 = std::min(H, y0 + ts);
            std::fill(acc_v.begin(), acc_v.end(), T(0));
            std::fill(Tr_v.begin(), Tr_v.end(), T(1));
            std::fill(last_v.begin(), last_v.end(), 0);
            std::fill(done_v.begin(), done_v.end(), 0);
            int64_t n_active = (x1 - x0) * (y1 - y0);
            td.load(ids + s, n, means2d, conics, opac, features, C);
            // Gaussian-major, front to back: each pixel still sees its Gaussians in depth order.
            for (int64_t k = 0; k < n && n_active > 0; ++k) {
                if (td.hy[k] < T(0)) continue;
                int64_t r_lo, r_hi;
                row_range(td, k, y0, y1, r_lo, r_hi);
                const T mx = td.mx[k], my = td.my[k], ca = td.ca[k], cb = td.cb[k], cc = td.cc[k];
                const T op = td.op[k], thr = td.thr[k];
                const int32_t k1 = int32_t(k + 1);
                const T *f = td.feat.data() + k * Cp;
                for (int64_t py = r_lo; py <= r_hi; ++py) {
                    const T dy = my - (T(py) + T(0.5));
                    int64_t x_lo, x_hi;
                    if (!row_span(td, k, dy, x0, x1, x_lo, x_hi)) continue;
                    const int64_t len = x_hi - x_lo + 1;
                    const T cdy = T(0.5) * cc * dy * dy, bdy = cb * dy, dx0 = mx - (T(x_lo) + T(0.5));
                    const int64_t p0 = (py - y0) * ts + (x_lo - x0);
                    T *Trp = Tr + p0;
                    int32_t *dp = done + p0, *lp = last + p0;
                    int32_t n_stop = 0;
#if M4DGS_SPAN8
                    if constexpr (std::is_same<T, float>::value) {
                        const __m256 one = _mm256_set1_ps(1.0f), t_min = _mm256_set1_ps(Consts<float>::t_min);
                        for (int64_t c0 = 0; c0 < len; c0 += SPAN8) {
                            const Span8 a8 = span_alpha8(ca, bdy, cdy, op, thr, dx0 - float(c0), len - c0);
                            const __m256i d = loadi8(dp + c0);
                            const __m256 valid = _mm256_andnot_ps(
                                _mm256_castsi256_ps(_mm256_cmpgt_epi32(d, _mm256_setzero_si256())), a8.ok);
                            const __m256 Tc = _mm256_loadu_ps(Trp + c0);
                            const __m256 next_T = _mm256_mul_ps(Tc, _mm256_sub_ps(one, a8.alpha));
                            const __m256 stop = _mm256_and_ps(valid, _mm256_cmp_ps(next_T, t_min, _CMP_LE_OQ));
                            const __m256 contrib = _mm256_andnot_ps(stop, valid);
                            _mm256_storeu_ps(wv + c0, _mm256_and_ps(contrib, _mm256_mul_ps(a8.alpha, Tc)));
                            const int cm = _mm256_movemask_ps(contrib), sm = _mm256_movemask_ps(stop);
                            if ((cm | sm) == 0) continue;
                            _mm256_storeu_ps(Trp + c0, _mm256_blendv_ps(Tc, next_T, contrib));
                            storei8(lp + c0, blendi8(loadi8(lp + c0), _mm256_set1_epi32(k1), contrib));
                            storei8(dp + c0, blendi8(d, _mm256_set1_epi32(1), stop));
                            n_stop += __builtin_popcount(unsigned(sm));
                        }
                    } else
#endif
                    {
                    // per pixel of the span: alpha, the skip / stop tests and the transmittance update
#pragma omp simd reduction(+ : n_stop)
                    for (int64_t i = 0; i < len; ++i) {
                        const T dx = dx0 - T(i);
                        const T sigma = T(0.5) * ca * dx * dx + bdy * dx + cdy;
                        const T alpha = std::min(Consts<T>::alpha_max, op * exp_neg(sigma));
                        const bool valid = (dp[i] == 0) & (sigma >= T(0)) & (sigma <= thr) &
                                           (alpha >= Consts<T>::alpha_min);
                        const T Tc = Trp[i];
                        const T next_T = Tc * (T(1) - alpha);
                        const bool stop = valid & (next_T <= Consts<T>::t_min);
                        const bool contrib = valid & !stop;
                        wv[i] = contrib ? alpha * Tc : T(0);
                        Trp[i] = contrib ? next_T : Tc;
                        lp[i] = contrib ? k1 : lp[i];
                        dp[i] = stop ? 1 : dp[i];
                        n_stop += stop ? 1 : 0;
                    }
                    }
                    n_active -= n_stop;
                    for (int64_t i = 0; i < len; ++i) {
                        const T w = wv[i];
                        if (w == T(0)) continue;
                        T *ap = acc + (p0 + i) * Cp;
#pragma omp simd
                        for (int64_t ch = 0; ch < Cp; ++ch) ap[ch] += w * f[ch];
                    }
                }
            }
            for (int64_t py = y0; py < y1; ++py) {
                for (int64_t px = x0; px < x1; ++px) {
                    const int64_t p = (py - y0) * ts + (px - x0), pix = py * W + px;
                    std::copy(acc + p * Cp, acc + p * Cp + C, out_feat + pix * C);
                    out_T[pix] = Tr[p];
                    out_last[pix] = last[p];
                }
            }
        }
    }
}

// grads layout per intersection (every row of the tile lists is written): [v_mx, v_my, v_conic_a, v_conic_b, v_conic_c, v_opacity, v_feat[C]]
template <typename T, int NB = 0>  // NB > 0: padded channel count NB * LANES known at compile time
void backward_kernel(const T *means2d, const T *conics, const T *opac, const T *features, int64_t C,
                     const int32_t *offsets, const int32_t *ids, int64_t W, int64_t H, int64_t ts,
                     int64_t tiles_x, int64_t tiles_y, int n_threads, const T *out_T, const int32_t *out_last,
                     const T *v_feat, const T *v_alpha, T *grads) {
    const int64_t n_tiles = tiles_x * tiles_y;
    const int64_t G = 6 + C;
    const int64_t P = ts * ts, Cp = NB > 0 ? int64_t(NB) * LANES : padded(C);
#pragma omp parallel num_threads(n_threads)
    {
        TileData<T> td;
        // vb[p] = sum_ch v_out[ch] * (features accumulated behind the current Gaussian)[ch], kept as a scalar
        std::vector<T> vb_v(P), Tr_v(P + SPAN8), vo_v(P * Cp), va_v(P), vf_v(Cp);
        std::vector<T> w_v(ts + SPAN8), ra_v(ts + SPAN8), Tp_v(ts + SPAN8), vis_v(ts + SPAN8), al_v(ts + SPAN8);
        std::vector<int32_t> last_v(P + SPAN8), geo_v(ts + SPAN8);
        T *vb = vb_v.data(), *Tr = Tr_v.data(), *vo = vo_v.data(), *va = va_v.data(), *vf = vf_v.data();
        T *wv = w_v.data(), *rav = ra_v.data(), *Tpv = Tp_v.data(), *visv = vis_v.data(), *alv = al_v.data();
        int32_t *last = last_v.data(), *geo = geo_v.data();
#pragma omp for schedule(dynamic, 1)
        for (int64_t t = 0; t < n_tiles; ++t) {
            const int64_t s = offsets[t], n = offsets[t + 1] - s;
            if (n == 0) continue;
            const int64_t tx = t % tiles_x, ty = t / tiles_x;
            const int64_t x0 = tx * ts, y0 = ty * ts;
            const int64_t x1 = std::min(W, x0 + ts), y1 = std::min(H, y0 + ts);
            int32_t max_last = 0;
            std::fill(last_v.begin(), last_v.end(), 0);
            for (int64_t py = y0; py < y1; ++py) {
                for (int64_t px = x0; px < x1; ++px) {
                    const int64_t p = (py - y0) * ts + (px - x0), pix = py * W + px;
                    last[p] = out_last[pix];
                    max_last = std::max(max_last, last[p]);
                    Tr[p] = out_T[pix];
                    // d alpha_out / d alpha_i = T_final / (1 - alpha_i): keep v_alpha * T_final per pixel
                    va[p] = v_alpha[pix] * out_T[pix];
                    std::copy(v_feat + pix * C, v_feat + (pix + 1) * C, vo + p * Cp);
                    std::fill(vo + p * Cp + C, vo + (p + 1) * Cp, T(0));
                }
            }
            // rows of Gaussians behind every pixel's last contributor get no gradient
            std::fill(grads + (s + max_last) * G, grads + (s + n) * G, T(0));
            if (max_last == 0) continue;
            std::fill(vb_v.begin(), vb_v.end(), T(0));
            td.load(ids + s, max_last, means2d, conics, opac, features, C);
            // Gaussian-major, back to front: each pixel sees its contributors in reverse depth order.
            for (int64_t k = max_last - 1; k >= 0; --k) {
                if (td.hy[k] < T(0)) {
                    std::fill(grads + (s + k) * G, grads + (s + k + 1) * G, T(0));
                    continue;
                }
                int64_t r_lo, r_hi;
                row_range(td, k, y0, y1, r_lo, r_hi);
                const T mx = td.mx[k], my = td.my[k], ca = td.ca[k], cb = td.cb[k], cc = td.cc[k];
                const T op = td.op[k], thr = td.thr[k];
                const int32_t k32 = int32_t(k);
                const T *f = td.feat.data() + k * Cp;
                T g_mx = 0, g_my = 0, g_a = 0, g_b = 0, g_c = 0, g_o = 0;
                bool any = false;
                std::fill(vf_v.begin(), vf_v.end(), T(0));
                for (int64_t py = r_lo; py <= r_hi; ++py) {
                    const T dy = my - (T(py) + T(0.5));
                    int64_t x_lo, x_hi;
                    if (!row_span(td, k, dy, x0, x1, x_lo, x_hi)) continue;
                    const int64_t len = x_hi - x_lo + 1;
                    const T cdy = T(0.5) * cc * dy * dy, bdy = cb * dy, dx0 = mx - (T(x_lo) + T(0.5));
                    const int64_t p0 = (py - y0) * ts + (x_lo - x0);
                    T *Trp = Tr + p0;
                    const int32_t *lp = last + p0;
                    int32_t n_valid = 0;
#if M4DGS_SPAN8
                    if constexpr (std::is_same<T, float>::value) {
                        const __m256 one = _mm256_set1_ps(1.0f);
                        const __m256 amax = _mm256_set1_ps(Consts<float>::alpha_max);
                        for (int64_t c0 = 0; c0 < len; c0 += SPAN8) {
                            const Span8 a8 = span_alpha8(ca, bdy, cdy, op, thr, dx0 - float(c0), len - c0);
                            const __m256 valid = _mm256_and_ps(
                                a8.ok, _mm256_castsi256_ps(_mm256_cmpgt_epi32(loadi8(lp + c0),
                                                                              _mm256_set1_epi32(k32))));
                            const __m256 ra = _mm256_div_ps(one, _mm256_sub_ps(one, a8.alpha));
                            const __m256 Tc = _mm256_loadu_ps(Trp + c0);
                            const __m256 Tp = _mm256_mul_ps(Tc, ra);  // transmittance in front of this Gaussian
                            _mm256_storeu_ps(Trp + c0, _mm256_blendv_ps(Tc, Tp, valid));
                            _mm256_storeu_ps(wv + c0, _mm256_and_ps(valid, _mm256_mul_ps(a8.alpha, Tp)));
                            _mm256_storeu_ps(rav + c0, ra);
                            _mm256_storeu_ps(Tpv + c0, Tp);
                            _mm256_storeu_ps(visv + c0, a8.vis);
                            _mm256_storeu_ps(alv + c0, a8.alpha);
                            const __m256 g = _mm256_and_ps(valid, _mm256_cmp_ps(a8.raw, amax, _CMP_LE_OQ));
                            storei8(geo + c0, _mm256_and_si256(_mm256_castps_si256(g), _mm256_set1_epi32(1)));
                            n_valid += __builtin_popcount(unsigned(_mm256_movemask_ps(valid)));
                        }
                    } else
#endif
                    {
                    // per pixel of the span: recompute alpha, step T back over this Gaussian
#pragma omp simd reduction(+ : n_valid)
                    for (int64_t i = 0; i < len; ++i) {
                        const T dx = dx0 - T(i);
                        const T sigma = T(0.5) * ca * dx * dx + bdy * dx + cdy;
                        const T vis = exp_neg(sigma);
                        const T raw = op * vis;
                        const T alpha = std::min(Consts<T>::alpha_max, raw);
                        const bool valid = (k32 < lp[i]) & (sigma >= T(0)) & (sigma <= thr) &
                                           (alpha >= Consts<T>::alpha_min);
                        const T ra = T(1) / (T(1) - alpha);
                        const T Tp = Trp[i] * ra;  // transmittance in front of this Gaussian
                        Trp[i] = valid ? Tp : Trp[i];
                        wv[i] = valid ? alpha * Tp : T(0);
                        rav[i] = ra;
                        Tpv[i] = Tp;
                        visv[i] = vis;
                        alv[i] = alpha;
                        geo[i] = (valid & (raw <= Consts<T>::alpha_max)) ? 1 : 0;
                        n_valid += valid ? 1 : 0;
                    }
                    }
                    if (n_valid == 0) continue;
                    any = true;
                    // per contributing pixel: the channel sums (feature gradient, d loss / d alpha), then the
                    // geometry and opacity gradients (none where alpha was clamped to 0.999, as in gsplat)
                    for (int64_t i = 0; i < len; ++i) {
                        const T w = wv[i];
                        if (w == T(0)) continue;
                        const int64_t p = p0 + i;
                        const T *vop = vo + p * Cp;
                        T v_f = 0;
#pragma omp simd reduction(+ : v_f)
                        for (int64_t ch = 0; ch < Cp; ++ch) {
                            vf[ch] += w * vop[ch];
                            v_f += vop[ch] * f[ch];
                        }
                        const T v_a = v_f * Tpv[i] + (va[p] - vb[p]) * rav[i];  // d loss / d alpha_i
                        vb[p] += v_f * w;
                        if (geo[i]) {
                            const T dx = dx0 - T(i);
                            g_o += v_a * visv[i];
                            const T v_sigma = -v_a * alv[i];
                            g_a += T(0.5) * dx * dx * v_sigma;
                            g_b += dx * dy * v_sigma;
                            g_c += T(0.5) * dy * dy * v_sigma;
                            g_mx += v_sigma * (ca * dx + cb * dy);
                            g_my += v_sigma * (cb * dx + cc * dy);
                        }
                    }
                }
                T *gk = grads + (s + k) * G;
                if (!any) {
                    std::fill(gk, gk + G, T(0));
                    continue;
                }
                gk[0] = g_mx; gk[1] = g_my; gk[2] = g_a; gk[3] = g_b; gk[4] = g_c; gk[5] = g_o;
                std::copy(vf, vf + C, gk + 6);
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------------------------
// Fused EWA projection (the cpu backend's replacement for the vectorised torch projection in projection.py; same
// formulas, hand-written backward). Per Gaussian: unit quaternion -> R, M = R diag(s), Mc = Rv M, camera mean
// pc = Rv m + t, J (pinhole with gsplat's fov clamp, or ortho), rows T0, T1 of J Mc, cov2d = (a, b, c) with eps2d on
// the diagonal, conic = inverse, means2d, depth = z. Culled Gaussians (z outside [near, far]) use z = 1 so the
// values stay finite; their outputs are unused.

template <typename T>
struct CamParams {
    T R[9], t[3], fx, fy, cx, cy, lxp, lxn, lyp, lyn, eps2d, near_plane, far_plane;
    bool ortho;
};

template <typename T>
struct ProjState {
    T q[4], qn, R[9], s[3], M[9], Mc[9], pc[3], iz, ux, uy, cx_clamped, cy_clamped, j00, j02, j11, j12, T0[3], T1[3],
        a, b, c, det;
    bool in_depth, det_ok;
};

template <typename T>
inline void proj_forward_one(const CamParams<T> &cp, const T *mean, const T *quat, const T *scale, ProjState<T> &st,
                             T *means2d, T *conic, T *depth, T *abc) {
    const T n2 = quat[0] * quat[0] + quat[1] * quat[1] + quat[2] * quat[2] + quat[3] * quat[3];
    st.qn = std::max(std::sqrt(n2), T(1e-12));
    for (int i = 0; i < 4; ++i) st.q[i] = quat[i] / st.qn;
    const T w = st.q[0], x = st.q[1], y = st.q[2], z = st.q[3];
    T *R = st.R;
    R[0] = 1 - 2 * (y * y + z * z); R[1] = 2 * (x * y - w * z);     R[2] = 2 * (x * z + w * y);
    R[3] = 2 * (x * y + w * z);     R[4] = 1 - 2 * (x * x + z * z); R[5] = 2 * (y * z - w * x);
    R[6] = 2 * (x * z - w * y);     R[7] = 2 * (y * z + w * x);     R[8] = 1 - 2 * (x * x + y * y);
    for (int j = 0; j < 3; ++j) st.s[j] = scale[j];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) st.M[3 * i + j] = R[3 * i + j] * st.s[j];
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j)
            st.Mc[3 * i + j] = cp.R[3 * i] * st.M[j] + cp.R[3 * i + 1] * st.M[3 + j] + cp.R[3 * i + 2] * st.M[6 + j];
        st.pc[i] = cp.R[3 * i] * mean[0] + cp.R[3 * i + 1] * mean[1] + cp.R[3 * i + 2] * mean[2] + cp.t[i];
    }
    const T zc = st.pc[2];
    st.in_depth = (zc >= cp.near_plane) && (zc <= cp.far_plane);
    if (cp.ortho) {
        for (int j = 0; j < 3; ++j) {
            st.T0[j] = cp.fx * st.Mc[j];
            st.T1[j] = cp.fy * st.Mc[3 + j];
        }
        means2d[0] = cp.fx * st.pc[0] + cp.cx;
        means2d[1] = cp.fy * st.pc[1] + cp.cy;
    } else {
        const T zs = st.in_depth ? zc : T(1);
        st.iz = T(1) / zs;
        const T rx = st.pc[0] * st.iz, ry = st.pc[1] * st.iz;
        st.ux = std::min(std::max(rx, -cp.lxn), cp.lxp);
        st.uy = std::min(std::max(ry, -cp.lyn), cp.lyp);
        st.cx_clamped = (rx < -cp.lxn || rx > cp.lxp) ? T(1) : T(0);
        st.cy_clamped = (ry < -cp.lyn || ry > cp.lyp) ? T(1) : T(0);
        st.j00 = cp.fx * st.iz;
        st.j02 = -cp.fx * st.ux * st.iz;
        st.j11 = cp.fy * st.iz;
        st.j12 = -cp.fy * st.uy * st.iz;
        for (int j = 0; j < 3; ++j) {
            st.T0[j] = st.j00 * st.Mc[j] + st.j02 * st.Mc[6 + j];
            st.T1[j] = st.j11 * st.Mc[3 + j] + st.j12 * st.Mc[6 + j];
        }
        means2d[0] = cp.fx * st.pc[0] * st.iz + cp.cx;
        means2d[1] = cp.fy * st.pc[1] * st.iz + cp.cy;
    }
    st.a = st.T0[0] * st.T0[0] + st.T0[1] * st.T0[1] + st.T0[2] * st.T0[2] + cp.eps2d;
    st.b = st.T0[0] * st.T1[0] + st.T0[1] * st.T1[1] + st.T0[2] * st.T1[2];
    st.c = st.T1[0] * st.T1[0] + st.T1[1] * st.T1[1] + st.T1[2] * st.T1[2] + cp.eps2d;
    st.det = st.a * st.c - st.b * st.b;
    st.det_ok = st.det > T(0);
    const T ds = st.det_ok ? st.det : T(1);
    conic[0] = st.c / ds;
    conic[1] = -st.b / ds;
    conic[2] = st.a / ds;
    depth[0] = zc;
    abc[0] = st.a;
    abc[1] = st.b;
    abc[2] = st.c;
}

// Accumulates into v_mean[3], v_quat[4], v_scale[3] (written) and v_Rv[9], v_t[3] (added).
template <typename T>
inline void proj_backward_one(const CamParams<T> &cp, const T *mean, const ProjState<T> &st, const T *v_m2d,
                              const T *v_con, T v_depth, T *v_mean, T *v_quat, T *v_scale, T *v_Rv, T *v_t) {
    // conic = (c, -b, a) / det
    T v_a = 0, v_b = 0, v_c = 0;
    if (st.det_ok) {
        const T id = T(1) / st.det, id2 = id * id;
        const T A = v_con[0], B = v_con[1], C = v_con[2];
        // d det = c da + a dc - 2 b db
        v_a = A * (-st.c * st.c * id2) + B * (st.b * st.c * id2) + C * (id - st.a * st.c * id2);
        v_b = A * (2 * st.b * st.c * id2) + B * (-id - 2 * st.b * st.b * id2) + C * (2 * st.a * st.b * id2);
        v_c = A * (id - st.a * st.c * id2) + B * (st.a * st.b * id2) + C * (-st.a * st.a * id2);
    }
    T v_T0[3], v_T1[3], v_Mc[9], v_pc[3];
    for (int j = 0; j < 3; ++j) {
        v_T0[j] = 2 * v_a * st.T0[j] + v_b * st.T1[j];
        v_T1[j] = 2 * v_c * st.T1[j] + v_b * st.T0[j];
    }
    if (cp.ortho) {
        for (int j = 0; j < 3; ++j) {
            v_Mc[j] = cp.fx * v_T0[j];
            v_Mc[3 + j] = cp.fy * v_T1[j];
            v_Mc[6 + j] = 0;
        }
        v_pc[0] = cp.fx * v_m2d[0];
        v_pc[1] = cp.fy * v_m2d[1];
        v_pc[2] = v_depth;
    } else {
        T v_j00 = 0, v_j02 = 0, v_j11 = 0, v_j12 = 0;
        for (int j = 0; j < 3; ++j) {
            v_j00 += v_T0[j] * st.Mc[j];
            v_j02 += v_T0[j] * st.Mc[6 + j];
            v_j11 += v_T1[j] * st.Mc[3 + j];
            v_j12 += v_T1[j] * st.Mc[6 + j];
            v_Mc[j] = st.j00 * v_T0[j];
            v_Mc[3 + j] = st.j11 * v_T1[j];
            v_Mc[6 + j] = st.j02 * v_T0[j] + st.j12 * v_T1[j];
        }
        const T x = st.pc[0], y = st.pc[1];
        T v_iz = cp.fx * v_j00 + cp.fy * v_j11 - cp.fx * st.ux * v_j02 - cp.fy * st.uy * v_j12;
        const T v_ux = -cp.fx * st.iz * v_j02, v_uy = -cp.fy * st.iz * v_j12;
        T v_x = cp.fx * st.iz * v_m2d[0], v_y = cp.fy * st.iz * v_m2d[1];
        v_iz += cp.fx * x * v_m2d[0] + cp.fy * y * v_m2d[1];
        if (st.cx_clamped == T(0)) {
            v_x += v_ux * st.iz;
            v_iz += v_ux * x;
        }
        if (st.cy_clamped == T(0)) {
            v_y += v_uy * st.iz;
            v_iz += v_uy * y;
        }
        v_pc[0] = v_x;
        v_pc[1] = v_y;
        v_pc[2] = v_depth + (st.in_depth ? -st.iz * st.iz * v_iz : T(0));
    }
    // Mc = Rv M, pc = Rv m + t
    T v_M[9];
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            v_M[3 * i + j] = cp.R[i] * v_Mc[j] + cp.R[3 + i] * v_Mc[3 + j] + cp.R[6 + i] * v_Mc[6 + j];
            v_Rv[3 * i + j] += v_Mc[3 * i] * st.M[3 * j] + v_Mc[3 * i + 1] * st.M[3 * j + 1] +
                               v_Mc[3 * i + 2] * st.M[3 * j + 2] + v_pc[i] * mean[j];
        }
        v_mean[i] = cp.R[i] * v_pc[0] + cp.R[3 + i] * v_pc[1] + cp.R[6 + i] * v_pc[2];
        v_t[i] += v_pc[i];
    }
    // M = R diag(s)
    T v_R[9];
    for (int j = 0; j < 3; ++j) {
        v_scale[j] = v_M[j] * st.R[j] + v_M[3 + j] * st.R[3 + j] + v_M[6 + j] * st.R[6 + j];
        for (int i = 0; i < 3; ++i) v_R[3 * i + j] = v_M[3 * i + j] * st.s[j];
    }
    // R(q) for the unit quaternion (w, x, y, z)
    const T w = st.q[0], x = st.q[1], y = st.q[2], z = st.q[3];
    const T *g = v_R;
    const T vw = 2 * (-z * g[1] + y * g[2] + z * g[3] - x * g[5] - y * g[6] + x * g[7]);
    const T vx = 2 * (y * g[1] + z * g[2] + y * g[3] - 2 * x * g[4] - w * g[5] + z * g[6] + w * g[7] - 2 * x * g[8]);
    const T vy = 2 * (-2 * y * g[0] + x * g[1] + w * g[2] + x * g[3] + z * g[5] - w * g[6] + z * g[7] - 2 * y * g[8]);
    const T vz = 2 * (-2 * z * g[0] - w * g[1] + x * g[2] + w * g[3] - 2 * z * g[4] + y * g[5] + x * g[6] + y * g[7]);
    // normalisation q / |q|
    const T dot = w * vw + x * vx + y * vy + z * vz;
    v_quat[0] = (vw - w * dot) / st.qn;
    v_quat[1] = (vx - x * dot) / st.qn;
    v_quat[2] = (vy - y * dot) / st.qn;
    v_quat[3] = (vz - z * dot) / st.qn;
}

template <typename T>
CamParams<T> make_cam(const T *viewmat, const T *K, bool ortho, int64_t W, int64_t H, double eps2d,
                      double near_plane, double far_plane) {
    CamParams<T> cp;
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) cp.R[3 * i + j] = viewmat[4 * i + j];
        cp.t[i] = viewmat[4 * i + 3];
    }
    cp.fx = K[0];
    cp.fy = K[4];
    cp.cx = K[2];
    cp.cy = K[5];
    const T tfx = T(0.5) * T(W) / cp.fx, tfy = T(0.5) * T(H) / cp.fy;
    cp.lxp = (T(W) - cp.cx) / cp.fx + T(0.3) * tfx;
    cp.lxn = cp.cx / cp.fx + T(0.3) * tfx;
    cp.lyp = (T(H) - cp.cy) / cp.fy + T(0.3) * tfy;
    cp.lyn = cp.cy / cp.fy + T(0.3) * tfy;
    cp.eps2d = T(eps2d);
    cp.near_plane = T(near_plane);
    cp.far_plane = T(far_plane);
    cp.ortho = ortho;
    return cp;
}

// Calls fn(std::integral_constant<int, NB>) with NB = padded(C) / LANES for common float channel counts
// (unrolled channel loops), NB = 0 (run-time count) otherwise.
template <typename T, typename Fn>
void with_channel_blocks(int64_t C, Fn fn) {
    if (std::is_same<T, float>::value) {
        switch (padded(C) / LANES) {
            case 1: fn(std::integral_constant<int, 1>{}); return;
            case 2: fn(std::integral_constant<int, 2>{}); return;
            case 3: fn(std::integral_constant<int, 3>{}); return;
            case 4: fn(std::integral_constant<int, 4>{}); return;
            case 5: fn(std::integral_constant<int, 5>{}); return;
            default: break;
        }
    }
    fn(std::integral_constant<int, 0>{});
}

}  // namespace

#ifndef M4DGS_KERNELS_ONLY
static void check_inputs(const torch::Tensor &means2d, const torch::Tensor &conics, const torch::Tensor &opac,
                  const torch::Tensor &features, const torch::Tensor &offsets, const torch::Tensor &ids) {
    TORCH_CHECK(means2d.device().is_cpu(), "rasterize_cpu: tensors must be on the CPU");
    TORCH_CHECK(means2d.dim() == 2 && means2d.size(1) == 2, "means2d must be [N, 2]");
    const int64_t N = means2d.size(0);
    TORCH_CHECK(conics.sizes() == torch::IntArrayRef({N, 3}), "conics must be [N, 3]");
    TORCH_CHECK(opac.dim() == 1 && opac.size(0) == N, "opacities must be [N]");
    TORCH_CHECK(features.dim() == 2 && features.size(0) == N, "features must be [N, C]");
    for (const auto *x : {&conics, &opac, &features})
        TORCH_CHECK(x->scalar_type() == means2d.scalar_type(), "all float inputs must share one dtype");
    for (const auto *x : {&means2d, &conics, &opac, &features, &offsets, &ids})
        TORCH_CHECK(x->is_contiguous(), "inputs must be contiguous");
    TORCH_CHECK(offsets.scalar_type() == torch::kInt32 && ids.scalar_type() == torch::kInt32,
                "offsets and ids must be int32");
}

// Returns (features [H, W, C], final transmittance [H, W], last [H, W] int32).
std::vector<torch::Tensor> rasterize_forward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor opac,
                                             torch::Tensor features, torch::Tensor offsets, torch::Tensor ids,
                                             int64_t W, int64_t H, int64_t tile_size, int64_t n_threads) {
    check_inputs(means2d, conics, opac, features, offsets, ids);
    const int64_t C = features.size(1);
    const int64_t tiles_x = (W + tile_size - 1) / tile_size, tiles_y = (H + tile_size - 1) / tile_size;
    TORCH_CHECK(offsets.numel() == tiles_x * tiles_y + 1, "offsets must have tiles_x * tiles_y + 1 entries");
    auto out_feat = torch::empty({H, W, C}, means2d.options());
    auto out_T = torch::empty({H, W}, means2d.options());
    auto out_last = torch::empty({H, W}, means2d.options().dtype(torch::kInt32));
    AT_DISPATCH_FLOATING_TYPES(means2d.scalar_type(), "rasterize_forward", [&] {
        with_channel_blocks<scalar_t>(C, [&](auto nb) {
            forward_kernel<scalar_t, decltype(nb)::value>(
                means2d.data_ptr<scalar_t>(), conics.data_ptr<scalar_t>(), opac.data_ptr<scalar_t>(),
                features.data_ptr<scalar_t>(), C, offsets.data_ptr<int32_t>(), ids.data_ptr<int32_t>(), W, H,
                tile_size, tiles_x, tiles_y, int(std::max<int64_t>(1, n_threads)), out_feat.data_ptr<scalar_t>(),
                out_T.data_ptr<scalar_t>(), out_last.data_ptr<int32_t>());
        });
    });
    return {out_feat, out_T, out_last};
}

// Returns per-Gaussian gradients [N, 6 + C]: (v_means2d[2], v_conics[3], v_opacity, v_features[C]).
torch::Tensor rasterize_backward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor opac,
                                 torch::Tensor features, torch::Tensor offsets, torch::Tensor ids, int64_t W,
                                 int64_t H, int64_t tile_size, int64_t n_threads, torch::Tensor out_T,
                                 torch::Tensor out_last, torch::Tensor v_feat, torch::Tensor v_alpha) {
    check_inputs(means2d, conics, opac, features, offsets, ids);
    const int64_t C = features.size(1), N = means2d.size(0), M = ids.size(0), G = 6 + C;
    const int64_t tiles_x = (W + tile_size - 1) / tile_size, tiles_y = (H + tile_size - 1) / tile_size;
    TORCH_CHECK(offsets.numel() == tiles_x * tiles_y + 1, "offsets must have tiles_x * tiles_y + 1 entries");
    TORCH_CHECK(v_feat.is_contiguous() && v_alpha.is_contiguous() && out_T.is_contiguous() &&
                    out_last.is_contiguous(), "backward inputs must be contiguous");
    TORCH_CHECK(v_feat.numel() == H * W * C && v_alpha.numel() == H * W, "gradient shapes do not match");
    TORCH_CHECK(v_feat.scalar_type() == means2d.scalar_type() && v_alpha.scalar_type() == means2d.scalar_type(),
                "gradient dtype does not match");
    auto per_isect = torch::empty({M, G}, means2d.options());  // every row is written by the kernel
    auto grads = torch::zeros({N, G}, means2d.options());
    AT_DISPATCH_FLOATING_TYPES(means2d.scalar_type(), "rasterize_backward", [&] {
        with_channel_blocks<scalar_t>(C, [&](auto nb) {
            backward_kernel<scalar_t, decltype(nb)::value>(
                means2d.data_ptr<scalar_t>(), conics.data_ptr<scalar_t>(), opac.data_ptr<scalar_t>(),
                features.data_ptr<scalar_t>(), C, offsets.data_ptr<int32_t>(), ids.data_ptr<int32_t>(), W, H,
                tile_size, tiles_x, tiles_y, int(std::max<int64_t>(1, n_threads)), out_T.data_ptr<scalar_t>(),
                out_last.data_ptr<int32_t>(), v_feat.data_ptr<scalar_t>(), v_alpha.data_ptr<scalar_t>(),
                per_isect.data_ptr<scalar_t>());
        });
        // serial, in list order: deterministic for a given binning
        const scalar_t *src = per_isect.data_ptr<scalar_t>();
        scalar_t *dst = grads.data_ptr<scalar_t>();
        const int32_t *idp = ids.data_ptr<int32_t>();
        for (int64_t m = 0; m < M; ++m) {
            scalar_t *d = dst + int64_t(idp[m]) * G;
            const scalar_t *g = src + m * G;
            for (int64_t j = 0; j < G; ++j) d[j] += g[j];
        }
    });
    return grads;
}

template <typename T>
void project_forward_impl(const CamParams<T> &cp, const T *mp, const T *qp, const T *sp, int64_t N, int nt, T *o_m,
                          T *o_c, T *o_d, T *o_a) {
#pragma omp parallel for schedule(static) num_threads(nt)
    for (int64_t n = 0; n < N; ++n) {
        ProjState<T> st;
        proj_forward_one(cp, mp + 3 * n, qp + 4 * n, sp + 3 * n, st, o_m + 2 * n, o_c + 3 * n, o_d + n, o_a + 3 * n);
    }
}

template <typename T>
void project_backward_impl(const CamParams<T> &cp, const T *mp, const T *qp, const T *sp, int64_t N, int nt,
                           const T *gm, const T *gc, const T *gd, T *o_m, T *o_q, T *o_s, T *vv) {
    // per-thread viewmat partial sums, combined in thread order (static schedule: deterministic)
    std::vector<T> partial(size_t(nt) * 12, T(0));
#pragma omp parallel num_threads(nt)
    {
        T *acc = partial.data() + 12 * omp_get_thread_num();
#pragma omp for schedule(static)
        for (int64_t n = 0; n < N; ++n) {
            ProjState<T> st;
            T m2[2], c3[3], d1, abc3[3];
            proj_forward_one(cp, mp + 3 * n, qp + 4 * n, sp + 3 * n, st, m2, c3, &d1, abc3);
            proj_backward_one(cp, mp + 3 * n, st, gm + 2 * n, gc + 3 * n, gd[n], o_m + 3 * n, o_q + 4 * n,
                              o_s + 3 * n, acc, acc + 9);
        }
    }
    for (int th = 0; th < nt; ++th) {
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j) vv[4 * i + j] += partial[12 * th + 3 * i + j];
            vv[4 * i + 3] += partial[12 * th + 9 + i];
        }
    }
}

static void check_projection_inputs(const torch::Tensor &means, const torch::Tensor &quats,
                                    const torch::Tensor &scales, const torch::Tensor &viewmat,
                                    const torch::Tensor &K) {
    TORCH_CHECK(means.device().is_cpu(), "projection: tensors must be on the CPU");
    const int64_t N = means.size(0);
    for (const auto *x : {&means, &quats, &scales, &viewmat, &K}) {
        TORCH_CHECK(x->is_contiguous() && x->scalar_type() == means.scalar_type(),
                    "projection inputs must be contiguous and share one dtype");
    }
    TORCH_CHECK(means.dim() == 2 && means.size(1) == 3 && quats.sizes() == torch::IntArrayRef({N, 4}) &&
                    scales.sizes() == torch::IntArrayRef({N, 3}) && viewmat.numel() == 16 && K.numel() == 9,
                "projection input shapes: means [N, 3], quats [N, 4], scales [N, 3], viewmat [4, 4], K [3, 3]");
}

// Fused projection forward: (means2d [N, 2], conics [N, 3], depths [N], cov2d (a, b, c) [N, 3]).
std::vector<torch::Tensor> project_forward(torch::Tensor means, torch::Tensor quats, torch::Tensor scales,
                                           torch::Tensor viewmat, torch::Tensor K, bool ortho, int64_t W, int64_t H,
                                           double eps2d, double near_plane, double far_plane, int64_t n_threads) {
    check_projection_inputs(means, quats, scales, viewmat, K);
    const int64_t N = means.size(0);
    auto m2d = torch::empty({N, 2}, means.options());
    auto con = torch::empty({N, 3}, means.options());
    auto dep = torch::empty({N}, means.options());
    auto abc = torch::empty({N, 3}, means.options());
    const int nt = int(std::max<int64_t>(1, n_threads));
    AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "project_forward", [&] {
        const auto cp = make_cam<scalar_t>(viewmat.data_ptr<scalar_t>(), K.data_ptr<scalar_t>(), ortho, W, H, eps2d,
                                           near_plane, far_plane);
        project_forward_impl<scalar_t>(cp, means.data_ptr<scalar_t>(), quats.data_ptr<scalar_t>(),
                                       scales.data_ptr<scalar_t>(), N, nt, m2d.data_ptr<scalar_t>(),
                                       con.data_ptr<scalar_t>(), dep.data_ptr<scalar_t>(), abc.data_ptr<scalar_t>());
    });
    return {m2d, con, dep, abc};
}

// Fused projection backward: (v_means [N, 3], v_quats [N, 4], v_scales [N, 3], v_viewmat [4, 4]).
std::vector<torch::Tensor> project_backward(torch::Tensor means, torch::Tensor quats, torch::Tensor scales,
                                            torch::Tensor viewmat, torch::Tensor K, bool ortho, int64_t W, int64_t H,
                                            double eps2d, double near_plane, double far_plane, int64_t n_threads,
                                            torch::Tensor v_means2d, torch::Tensor v_conics, torch::Tensor v_depths) {
    check_projection_inputs(means, quats, scales, viewmat, K);
    const int64_t N = means.size(0);
    for (const auto *x : {&v_means2d, &v_conics, &v_depths}) {
        TORCH_CHECK(x->is_contiguous() && x->scalar_type() == means.scalar_type(),
                    "projection gradients must be contiguous and share the input dtype");
    }
    TORCH_CHECK(v_means2d.numel() == 2 * N && v_conics.numel() == 3 * N && v_depths.numel() == N,
                "projection gradient shapes");
    auto v_means = torch::empty({N, 3}, means.options());
    auto v_quats = torch::empty({N, 4}, means.options());
    auto v_scales = torch::empty({N, 3}, means.options());
    auto v_view = torch::zeros({4, 4}, means.options());
    const int nt = int(std::max<int64_t>(1, n_threads));
    AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "project_backward", [&] {
        const auto cp = make_cam<scalar_t>(viewmat.data_ptr<scalar_t>(), K.data_ptr<scalar_t>(), ortho, W, H, eps2d,
                                           near_plane, far_plane);
        project_backward_impl<scalar_t>(cp, means.data_ptr<scalar_t>(), quats.data_ptr<scalar_t>(),
                                        scales.data_ptr<scalar_t>(), N, nt, v_means2d.data_ptr<scalar_t>(),
                                        v_conics.data_ptr<scalar_t>(), v_depths.data_ptr<scalar_t>(),
                                        v_means.data_ptr<scalar_t>(), v_quats.data_ptr<scalar_t>(),
                                        v_scales.data_ptr<scalar_t>(), v_view.data_ptr<scalar_t>());
    });
    return {v_means, v_quats, v_scales, v_view};
}

// Tile binning (the compiled counterpart of binning.bin_gaussians, same tile ranges): `order` lists the visible
// Gaussians front to back; a counting sort by tile keeps that order inside each tile. Returns (offsets
// [tiles + 1] int32, flat_ids [M] int32).
std::vector<torch::Tensor> bin_tiles(torch::Tensor means2d, torch::Tensor radii, torch::Tensor order, int64_t W,
                                     int64_t H, int64_t tile_size) {
    TORCH_CHECK(means2d.device().is_cpu() && means2d.is_contiguous() && radii.is_contiguous() &&
                    order.is_contiguous(), "bin_tiles: contiguous CPU tensors expected");
    TORCH_CHECK(radii.scalar_type() == torch::kInt32 && order.scalar_type() == torch::kInt64,
                "bin_tiles: radii int32, order int64");
    const int64_t tiles_x = (W + tile_size - 1) / tile_size, tiles_y = (H + tile_size - 1) / tile_size;
    const int64_t n_tiles = tiles_x * tiles_y, nv = order.numel();
    auto offsets = torch::zeros({n_tiles + 1}, means2d.options().dtype(torch::kInt32));
    std::vector<int64_t> box(size_t(nv) * 4);
    std::vector<int64_t> count(size_t(n_tiles) + 1, 0);
    const int64_t *ord = order.data_ptr<int64_t>();
    const int32_t *rad = radii.data_ptr<int32_t>();
    AT_DISPATCH_FLOATING_TYPES(means2d.scalar_type(), "bin_tiles", [&] {
        const scalar_t *m = means2d.data_ptr<scalar_t>();
        const double ts = double(tile_size);
        auto clampi = [](double v, int64_t hi) -> int64_t {
            if (!(v > 0.0)) return 0;
            if (v > double(hi)) return hi;
            return int64_t(v);
        };
        for (int64_t i = 0; i < nv; ++i) {
            const int64_t g = ord[i];
            const double mx = double(m[2 * g]) / ts, my = double(m[2 * g + 1]) / ts;
            const double rx = double(rad[2 * g]) / ts, ry = double(rad[2 * g + 1]) / ts;
            int64_t *b = box.data() + 4 * i;
            b[0] = clampi(std::floor(mx - rx), tiles_x);
            b[1] = clampi(std::ceil(mx + rx), tiles_x);
            b[2] = clampi(std::floor(my - ry), tiles_y);
            b[3] = clampi(std::ceil(my + ry), tiles_y);
            for (int64_t ty = b[2]; ty < b[3]; ++ty)
                for (int64_t tx = b[0]; tx < b[1]; ++tx) ++count[ty * tiles_x + tx + 1];
        }
    });
    for (int64_t t = 0; t < n_tiles; ++t) count[t + 1] += count[t];
    const int64_t M = count[n_tiles];
    TORCH_CHECK(M < (int64_t(1) << 31), "bin_tiles: too many intersections for int32 offsets");
    auto flat_ids = torch::empty({M}, means2d.options().dtype(torch::kInt32));
    int32_t *off = offsets.data_ptr<int32_t>(), *ids = flat_ids.data_ptr<int32_t>();
    for (int64_t t = 0; t <= n_tiles; ++t) off[t] = int32_t(count[t]);
    for (int64_t i = 0; i < nv; ++i) {
        const int64_t *b = box.data() + 4 * i;
        for (int64_t ty = b[2]; ty < b[3]; ++ty)
            for (int64_t tx = b[0]; tx < b[1]; ++tx) ids[count[ty * tiles_x + tx]++] = int32_t(ord[i]);
    }
    return {offsets, flat_ids};
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
    m.def("forward", &rasterize_forward, "tile rasterization forward (CPU)");
    m.def("backward", &rasterize_backward, "tile rasterization backward (CPU)");
    m.def("project_forward", &project_forward, "fused EWA projection forward (CPU)");
    m.def("bin_tiles", &bin_tiles, "tile binning by counting sort (CPU)");
    m.def("project_backward", &project_backward, "fused EWA projection backward (CPU)");
}
#endif  // M4DGS_KERNELS_ONLY
