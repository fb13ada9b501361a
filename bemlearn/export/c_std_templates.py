"""C99 text of the exported predictor's std: latent variance (eq. 12), the band's gradient and estimator terms (eq. B1).

Filled by :mod:`c_source` with the placeholders of :mod:`c_templates` (``${p}``, ``${P}``,
``$real``), ``${name}`` (``bem`` or ``full``), ``$n`` (its input count) and, for the dense and
factored forms, ``$signed_term``.  ``${p}_latent_var(k)`` returns max(0, var0 − Σ s_i v_i²) and
overwrites the kernel row k (exact GP); ``${p}_${name}_gradient2(v, k, h_n)`` returns Σ_i g_i²
and ``${p}_estimator2(k)`` returns Σ_k ε_k² (one function for the BEM and the full map: the
estimator weights E do not depend on the inputs); both must run before it.
"""

from string import Template

__all__ = ["TRIANGULAR_STD", "FACTORED_STD", "DENSE_STD", "BAND_GRADIENT", "NO_BAND_GRADIENT", "ESTIMATOR_TERM", "NO_ESTIMATOR_TERM"]

# Exact GP: forward substitution (L / gain) v = k in place, L packed row by row; returns the
# latent variance max(0, var0 − Σ v_i²).
TRIANGULAR_STD = Template(r"""static $real ${p}_latent_var($real *k)
{
    const $real *row = ${p}_factor;
    $real s, q = 0, r = 0, y, t;   /* q: compensated (Kahan) sum of v_i^2, r its running error */
    int i, j;
    $real a0, a1, a2, a3;          /* four partial sums: independent chains the CPU can overlap */
    for (i = 0; i < ${P}_N_SUPPORT; ++i) {
        a0 = a1 = a2 = a3 = 0;
        for (j = 0; j + 4 <= i; j += 4) {
            a0 += row[j] * k[j];
            a1 += row[j + 1] * k[j + 1];
            a2 += row[j + 2] * k[j + 2];
            a3 += row[j + 3] * k[j + 3];
        }
        for (; j < i; ++j) a0 += row[j] * k[j];
        s = (k[i] - ((a0 + a1) + (a2 + a3))) / row[i];
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

# Factored sgpr / svgp (S = L⁻ᵀ Rᵀ diag(s) R L⁻¹): forward substitution (L / gain) v = k in place, as
# for an exact GP, then r = R v (R dense, row-major) and the latent variance max(0, var0 − Σ_i s_i r_i²).
FACTORED_STD = Template(r"""static $real ${p}_latent_var($real *k)
{
    const $real *row = ${p}_factor;
    $real s, q = 0, r = 0, y, t;   /* q: compensated (Kahan) sum of s_i r_i^2, r its running error */
    int i, j;
    $real a0, a1, a2, a3;          /* four partial sums: independent chains the CPU can overlap */
    for (i = 0; i < ${P}_N_SUPPORT; ++i) {
        a0 = a1 = a2 = a3 = 0;
        for (j = 0; j + 4 <= i; j += 4) {
            a0 += row[j] * k[j];
            a1 += row[j + 1] * k[j + 1];
            a2 += row[j + 2] * k[j + 2];
            a3 += row[j + 3] * k[j + 3];
        }
        for (; j < i; ++j) a0 += row[j] * k[j];
        k[i] = (k[i] - ((a0 + a1) + (a2 + a3))) / row[i];
        row += i + 1;
    }
    for (i = 0; i < ${P}_N_SUPPORT; ++i) {
        const $real *g = ${p}_inner + (size_t)i * ${P}_N_SUPPORT;
        a0 = a1 = a2 = a3 = 0;
        for (j = 0; j + 4 <= ${P}_N_SUPPORT; j += 4) {
            a0 += g[j] * k[j];
            a1 += g[j + 1] * k[j + 1];
            a2 += g[j + 2] * k[j + 2];
            a3 += g[j + 3] * k[j + 3];
        }
        for (; j < ${P}_N_SUPPORT; ++j) a0 += g[j] * k[j];
        s = (a0 + a1) + (a2 + a3);
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
    $real s, q = 0, r = 0, y, t, a0, a1, a2, a3;   /* q: compensated (Kahan) sum of s_i v_i^2, r its error */
    int i, j;
    for (i = 0; i < ${P}_N_SUPPORT; ++i) {
        const $real *g = ${p}_factor + (size_t)i * ${P}_N_SUPPORT;
        a0 = a1 = a2 = a3 = 0;         /* four partial sums: independent chains the CPU can overlap */
        for (j = 0; j + 4 <= ${P}_N_SUPPORT; j += 4) {
            a0 += g[j] * k[j];
            a1 += g[j + 1] * k[j + 1];
            a2 += g[j + 2] * k[j + 2];
            a3 += g[j + 3] * k[j + 3];
        }
        for (; j < ${P}_N_SUPPORT; ++j) a0 += g[j] * k[j];
        s = (a0 + a1) + (a2 + a3);
        y = $signed_term - r;
        t = q + y;
        r = (t - q) - y;
        q = t;
    }
    s = ${p}_var0 - q;
    return s > 0 ? s : ($real)0;
}
""")

# Σ_i g_i² of the band (eq. B1): h_i = Σ_j P_ij k_j (four partial sums), g_i = h_i + γ_i v_i h_n,
# h_n = Σ_j w_j k_j = μ − y0 (the mean's own sum).
BAND_GRADIENT = Template(r"""static $real ${p}_${name}_gradient2(const $real *v, const $real *k, $real hn)
{
    $real g, sum = 0, a0, a1, a2, a3;
    int i, j;
    for (i = 0; i < $n; ++i) {
        const $real *pi = ${p}_${name}_P + (size_t)i * ${P}_N_SUPPORT;
        a0 = a1 = a2 = a3 = 0;
        for (j = 0; j + 4 <= ${P}_N_SUPPORT; j += 4) {
            a0 += pi[j] * k[j];
            a1 += pi[j + 1] * k[j + 1];
            a2 += pi[j + 2] * k[j + 2];
            a3 += pi[j + 3] * k[j + 3];
        }
        for (; j < ${P}_N_SUPPORT; ++j) a0 += pi[j] * k[j];
        g = ((a0 + a1) + (a2 + a3)) + ${p}_${name}_gamma[i] * (v[i] * hn);
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

# Σ_k ε_k² of the band (eq. B1): ε_k = Σ_j E_kj k_j (four partial sums, like the gradient's h_i),
# E_kj = y_std σ_f² δ_jk / √K, so ε_k = y_std k_Z(x̃)ᵀ δ_k / √K is the mean's shift under estimator k over √K.
ESTIMATOR_TERM = Template(r"""static $real ${p}_estimator2(const $real *k)
{
    $real e, sum = 0, a0, a1, a2, a3;
    int i, j;
    for (i = 0; i < ${P}_N_ESTIMATORS; ++i) {
        const $real *ei = ${p}_E + (size_t)i * ${P}_N_SUPPORT;
        a0 = a1 = a2 = a3 = 0;
        for (j = 0; j + 4 <= ${P}_N_SUPPORT; j += 4) {
            a0 += ei[j] * k[j];
            a1 += ei[j + 1] * k[j + 1];
            a2 += ei[j + 2] * k[j + 2];
            a3 += ei[j + 3] * k[j + 3];
        }
        for (; j < ${P}_N_SUPPORT; ++j) a0 += ei[j] * k[j];
        e = (a0 + a1) + (a2 + a3);
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
