"""C99 text of the exported predictor's std: latent variance (eq. 12), the band's gradient and estimator terms (eq. B1).

Filled by :mod:`c_source` with the placeholders of :mod:`c_templates` (``${p}``, ``${P}``,
``$real``), ``${name}`` (``bem`` or ``full``), ``$n`` (its input count) and, for the dense and
factored forms, ``$signed_term``.  ``${p}_latent_var(k)`` returns max(0, var0 − Σ s_i v_i²) and
overwrites the kernel row k (exact GP); ``${p}_${name}_gradient2(v, k, h_n)`` returns Σ_i g_i²
and ``${p}_estimator2(k)`` returns Σ_k ε_k² (one function for the BEM and the full map: the
estimator weights E do not depend on the inputs); both must run before it.  :data:`KERNELS`
(``${p}_dot``, ``${p}_solve_lower``) comes first: every other block calls them.
"""

from string import Template

__all__ = ["KERNELS", "TRIANGULAR_STD", "FACTORED_STD", "DENSE_STD", "BAND_GRADIENT", "NO_BAND_GRADIENT", "ESTIMATOR_TERM", "NO_ESTIMATOR_TERM"]

# Shared by every block below: a dot product with four partial sums (independent chains the CPU
# can overlap), and forward substitution (L / gain) v = k in place, L packed row by row.
# ``static inline``: a block that does not use one raises no unused-function warning.
KERNELS = Template(r"""static inline $real ${p}_dot(const $real *a, const $real *k, int n)
{
    $real a0 = 0, a1 = 0, a2 = 0, a3 = 0;
    int j;
    for (j = 0; j + 4 <= n; j += 4) {
        a0 += a[j] * k[j];
        a1 += a[j + 1] * k[j + 1];
        a2 += a[j + 2] * k[j + 2];
        a3 += a[j + 3] * k[j + 3];
    }
    for (; j < n; ++j) a0 += a[j] * k[j];
    return (a0 + a1) + (a2 + a3);
}

static inline void ${p}_solve_lower($real *k)
{
    const $real *row = ${p}_factor;
    int i;
    for (i = 0; i < ${P}_N_SUPPORT; ++i) {
        k[i] = (k[i] - ${p}_dot(row, k, i)) / row[i];
        row += i + 1;
    }
}
""")

# Exact GP: v = (L / gain)⁻¹ k in place; returns the latent variance max(0, var0 − Σ v_i²).
TRIANGULAR_STD = Template(r"""static $real ${p}_latent_var($real *k)
{
    const $real *row = ${p}_factor;
    $real s, q = 0, r = 0, y, t;   /* q: compensated (Kahan) sum of v_i^2, r its running error */
    int i;
    for (i = 0; i < ${P}_N_SUPPORT; ++i) {   /* ${p}_solve_lower with the sum fused into its pass */
        s = (k[i] - ${p}_dot(row, k, i)) / row[i];
        k[i] = s;
        y = s * s - r;
        t = q + y;
        r = (t - q) - y;
        q = t;
        row += i + 1;
    }
    s = ${p}_var0 - q;
    return s > 0 ? s : ($real)0;
}
""")

# Factored sgpr / svgp (S = L⁻ᵀ Rᵀ diag(s) R L⁻¹): v = (L / gain)⁻¹ k in place, as for an exact GP,
# then r = R v (R dense, row-major) and the latent variance max(0, var0 − Σ_i s_i r_i²).
FACTORED_STD = Template(r"""static $real ${p}_latent_var($real *k)
{
    $real s, q = 0, r = 0, y, t;   /* q: compensated (Kahan) sum of s_i r_i^2, r its running error */
    int i;
    ${p}_solve_lower(k);
    for (i = 0; i < ${P}_N_SUPPORT; ++i) {
        s = ${p}_dot(${p}_inner + (size_t)i * ${P}_N_SUPPORT, k, ${P}_N_SUPPORT);
        y = $signed_term - r;
        t = q + y;
        r = (t - q) - y;
        q = t;
    }
    s = ${p}_var0 - q;
    return s > 0 ? s : ($real)0;
}
""")

# sgpr / svgp (unfactored): v = G k, latent variance max(0, var0 − Σ_i s_i v_i²).
DENSE_STD = Template(r"""static $real ${p}_latent_var($real *k)
{
    $real s, q = 0, r = 0, y, t;   /* q: compensated (Kahan) sum of s_i v_i^2, r its error */
    int i;
    for (i = 0; i < ${P}_N_SUPPORT; ++i) {
        s = ${p}_dot(${p}_factor + (size_t)i * ${P}_N_SUPPORT, k, ${P}_N_SUPPORT);
        y = $signed_term - r;
        t = q + y;
        r = (t - q) - y;
        q = t;
    }
    s = ${p}_var0 - q;
    return s > 0 ? s : ($real)0;
}
""")

# Σ_i g_i² of the band (eq. B1): h_i = Σ_j P_ij k_j, g_i = h_i + γ_i v_i h_n,
# h_n = Σ_j w_j k_j = μ − y0 (the mean's own kernel sum); a linear prior mean adds its constant sb_i.
BAND_GRADIENT = Template(r"""static $real ${p}_${name}_gradient2(const $real *v, const $real *k, $real hn)
{
    $real g, sum = 0;
    int i;
    for (i = 0; i < $n; ++i) {
        g = ${p}_dot(${p}_${name}_P + (size_t)i * ${P}_N_SUPPORT, k, ${P}_N_SUPPORT) + ${p}_${name}_gamma[i] * (v[i] * hn)$sb_term;
        sum += g * g;
    }
    return sum;
}
""")

# No input noise (every s_i = 0): the band is c times the latent std.
NO_BAND_GRADIENT = Template(r"""static $real ${p}_${name}_gradient2(const $real *v, const $real *k, $real hn)
{
    (void)v;
    (void)k;
    (void)hn;
    return 0;
}
""")

# Σ_k ε_k² of the band (eq. B1): ε_k = Σ_j E_kj k_j, E_kj = y_std σ_f² δ_jk / √K, so
# ε_k = y_std k_Z(x̃)ᵀ δ_k / √K is the mean's k-th shift column over √K (a neighbouring derivative estimator,
# or the deviation from other draws of the training rows: pipeline.uncertainty).
ESTIMATOR_TERM = Template(r"""static $real ${p}_estimator2(const $real *k)
{
    $real e, sum = 0;
    int i;
    for (i = 0; i < ${P}_N_ESTIMATORS; ++i) {
        e = ${p}_dot(${p}_E + (size_t)i * ${P}_N_SUPPORT, k, ${P}_N_SUPPORT);
        sum += e * e;
    }
    return sum;
}
""")

# No estimator columns (K = 0): no estimator term.
NO_ESTIMATOR_TERM = Template(r"""static $real ${p}_estimator2(const $real *k)
{
    (void)k;
    return 0;
}
""")
