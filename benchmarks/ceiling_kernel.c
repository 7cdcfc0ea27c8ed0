/* Fused toy step of the campaign's shape: the machine's ceiling for benchmarks/campaign_throughput.py.
 *
 * One step of one scenario: pilot doublet, PI roll-rate law, nonlinear actuator (valve current
 * saturation, closed-form rate with the hinge load, exponential update over the sample), roll
 * axis, three turbulence filters, sensor noise, four hash-based standard normals (the same hash
 * and inverse-CDF transform as mcfdd.analysis.noise, with Giles' float32 erfinv polynomials),
 * a bank of six LPV residual filters with Narendra evaluators, the excitation band-pass with its
 * evaluator, the stall filter with its evaluator, and running reductions (largest ratio per
 * filter, first detection time). It is not the campaign's step (no gates, no confirmation, no
 * stall bookkeeping): a lower bound on the work of a step of this shape, written as one loop
 * the compiler can keep in registers and vectorise over LANES scenarios.
 *
 * Built by the benchmark with gcc (-O3 -march=native -fopenmp, with or without -ffast-math) and
 * called through ctypes; scenarios are split over OpenMP threads in blocks of LANES.
 */
#include <math.h>
#include <stdint.h>

#define LANES 16
#define NM 6

static inline uint32_t mix(uint32_t x) {
    x ^= x >> 16; x *= 0x7feb352du; x ^= x >> 15; x *= 0x846ca68bu; return x ^ (x >> 16);
}

static inline float erfinv_giles(float x) {
    /* both polynomials, then a select: branch-free, so the lane loop vectorises */
    float w = -logf((1.0f - x) * (1.0f + x));
    float a = w - 2.5f, q = sqrtf(w) - 3.0f, p, r;
    p = 2.81022636e-08f; p = 3.43273939e-07f + p * a; p = -3.5233877e-06f + p * a;
    p = -4.39150654e-06f + p * a; p = 0.00021858087f + p * a; p = -0.00125372503f + p * a;
    p = -0.00417768164f + p * a; p = 0.246640727f + p * a; p = 1.50140941f + p * a;
    r = -0.000200214257f; r = 0.000100950558f + r * q; r = 0.00134934322f + r * q;
    r = -0.00367342844f + r * q; r = 0.00573950773f + r * q; r = -0.0076224613f + r * q;
    r = 0.00943887047f + r * q; r = 1.00167406f + r * q; r = 2.83297682f + r * q;
    return (w < 5.0f ? p : r) * x;
}

static inline float normal(uint32_t k0, uint32_t k1, uint32_t counter) {
    uint32_t m = mix(mix(counter ^ k0) + k1) >> 9;
    return 1.41421356f * erfinv_giles((float)(2 * (int32_t)m + 1) * 1.1920929e-07f - 1.0f);
}

static inline float box(float t, float a, float b, float r) {
    return fminf(fmaxf(fminf(t - a, b - t) / r, 0.0f), 1.0f);
}

/* n scenarios (a multiple of LANES), n_steps steps; per-scenario inputs and outputs are arrays of n.
 * coef: (NM, 4, n) scheduled LPV coefficients (C0..C3 at the scenario's flight point), k0: (NM,),
 * keys: (2, n) key words; ratio_max: (NM, n). */
void run(int n, int n_steps, const float *amp, const float *t0, const float *dur, const float *kp_law,
         const float *ki_law, const float *load0, const float *slope, const float *lp, const float *lda,
         const float *gust_a, const float *gust_b, const float *coef, const float *k0, const uint32_t *keys_in,
         float *ratio_max, float *det_time, float *stall_max) {
    const float dt = 0.01f, imax = 8e-3f, kpa = 2.18f, kci = 11.46f, dp = 2.07e7f,
                s_area = 2.272e-3f, kd = 5.6e5f, r_arm = 0.0525f, xmax = 0.0525f * 0.4363f, pole = 20.0f,
                gamma = 1.0f, alpha = 0.1f, beta = 1.0f, tau = 0.3f, x_scale = 0.0229f;
    const float phi_a = expf(-pole * dt), decay = expf(-gamma * dt), ev = beta * (1.0f - decay) / gamma;
    #pragma omp parallel for schedule(static)
    for (int b = 0; b < n / LANES; b++) {
        float x[LANES], p[LANES], phi[LANES], integ[LANES], g[3][LANES], xq[NM][LANES], xi[NM][LANES],
            band_m[LANES], band_o[LANES], band_xi[LANES], sq[LANES], sxi[LANES], smax[LANES], rmax[NM][LANES],
            det[LANES];
        float A[LANES], T0[LANES], D[LANES], KP[LANES], KI[LANES], L0[LANES], SL[LANES], LP[LANES], LDA[LANES],
            GA[LANES], GB[LANES], C[NM][4][LANES];
        uint32_t K0[LANES], K1[LANES];
        for (int l = 0; l < LANES; l++) {
            int s = b * LANES + l;
            A[l] = amp[s]; T0[l] = t0[s]; D[l] = dur[s]; KP[l] = kp_law[s]; KI[l] = ki_law[s]; L0[l] = load0[s];
            SL[l] = slope[s]; LP[l] = lp[s]; LDA[l] = lda[s]; GA[l] = gust_a[s]; GB[l] = gust_b[s];
            K0[l] = keys_in[s]; K1[l] = keys_in[n + s];
            for (int i = 0; i < NM; i++)
                for (int j = 0; j < 4; j++) C[i][j][l] = coef[(i * 4 + j) * n + s];
        }
        for (int l = 0; l < LANES; l++) {
            x[l] = p[l] = phi[l] = integ[l] = band_o[l] = band_xi[l] = sxi[l] = 0.0f;
            band_m[l] = sq[l] = 0.0f; det[l] = INFINITY; smax[l] = -INFINITY;
            for (int j = 0; j < 3; j++) g[j][l] = 0.0f;
            for (int i = 0; i < NM; i++) { xq[i][l] = 0.0f; xi[i][l] = 0.0f; rmax[i][l] = -INFINITY; }
        }
        for (int k = 0; k < n_steps; k++) {
            #pragma omp simd
            for (int l = 0; l < LANES; l++) {
                float t = k * dt, tt = t - T0[l], d = D[l];
                float stick = A[l] * (box(tt, 0.0f, d, 0.3f) - box(tt, d, 2.0f * d, 0.3f));
                uint32_t c = (uint32_t)k * 4u;
                float n0 = normal(K0[l], K1[l], c), n1 = normal(K0[l], K1[l], c + 1),
                      n2 = normal(K0[l], K1[l], c + 2), n3 = normal(K0[l], K1[l], c + 3);
                g[0][l] = GA[l] * g[0][l] + GB[l] * n0;
                g[1][l] = GA[l] * g[1][l] + GB[l] * n1;
                g[2][l] = GA[l] * g[2][l] + GB[l] * n2;
                float pc = fminf(fmaxf(0.26f * stick, -0.5f * (1.17f + phi[l])), 0.5f * (1.17f - phi[l]));
                float e = pc - p[l], raw = KP[l] * e + KI[l] * integ[l];
                float dc = fminf(fmaxf(raw, -0.4363f), 0.4363f);
                integ[l] += (fabsf(raw) > 0.4363f) ? 0.0f : dt * e;
                float uc = dc * r_arm, ea = uc - x[l];
                float sat = imax / fmaxf(kpa * fabsf(ea), imax);
                float cur = kci * kpa * ea * sat, gg = cur * cur / dp;
                float fa = L0[l] + SL[l] * x[l] / r_arm;
                float av = dp - copysignf(1.0f, ea) * fa / s_area;
                float kk = kci * kpa * sat * sqrtf(fmaxf(av, 0.0f) / (dp * (1.0f + gg * kd / s_area)));
                float u = x[l] + 5e-5f * n3, dir = (ea > 0.0f) - (ea < 0.0f), xn = u / x_scale;
                float xnew = uc - ea * expf(-kk * dt);
                x[l] = fminf(fmaxf(xnew, -xmax), xmax);
                p[l] += dt * (LP[l] * p[l] + LDA[l] * x[l] / r_arm + g[1][l]);
                phi[l] += dt * p[l];
                float bp = band_o[l];
                float ph0 = expf(-k0[0] * dt);
                band_o[l] = phi_a * band_o[l] + (1.0f - phi_a) * (uc - band_m[l]);
                band_m[l] = ph0 * band_m[l] + (1.0f - ph0) * uc;
                float theta_u = band_xi[l] + alpha * fabsf(bp);
                band_xi[l] = decay * band_xi[l] + ev * fabsf(bp);
                int excited = theta_u >= 1e-6f;
                float k_free = 0.0f;
                #pragma GCC unroll 6
                for (int i = 0; i < NM; i++) {
                    float ki = C[i][0][l] + C[i][1][l] * dir + xn * (C[i][2][l] + C[i][3][l] * dir);
                    float ph = expf(-ki * dt), cc = (1.0f - phi_a) / (1.0f - expf(-k0[i] * dt));
                    float r = cc * (xq[i][l] + u);
                    xq[i][l] = phi_a * xq[i][l] + (phi_a - ph) * u - (1.0f - ph) * uc;
                    float th = xi[i][l] + alpha * fabsf(r);
                    xi[i][l] = decay * xi[i][l] + ev * fabsf(r);
                    float ratio = th / (excited ? theta_u : 1.0f);
                    rmax[i][l] = excited ? fmaxf(rmax[i][l], ratio) : rmax[i][l];
                    if (i == 0) {
                        det[l] = (excited && ratio >= tau && det[l] > 1e30f) ? t : det[l];
                        k_free = ki;
                    }
                }
                float phs = expf(-k_free * dt), cs = (1.0f - phi_a) / (1.0f - expf(-k0[0] * dt));
                float rs = cs * (sq[l] + u);
                sq[l] = phi_a * sq[l] + (phi_a - phs) * u - (1.0f - phs) * uc;
                smax[l] = fmaxf(smax[l], sxi[l] + alpha * fabsf(rs));
                sxi[l] = decay * sxi[l] + ev * fabsf(rs);
            }
        }
        for (int l = 0; l < LANES; l++) {
            int s = b * LANES + l;
            for (int i = 0; i < NM; i++) ratio_max[i * n + s] = rmax[i][l];
            det_time[s] = det[l];
            stall_max[s] = smax[l];
        }
    }
}
