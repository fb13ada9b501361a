"""C99 text of the exp of one block of 32 exponents (``<prefix>_exp_block``), filled by :mod:`c_source`.

The mean (eq. 12) needs exp(e_j) for every support point; libm's ``exp`` is a scalar call
that the compiler cannot vectorize, and it dominates a query.  The float64 block below is
branch-free with a fixed trip count, so compilers vectorize it at -O2 (docs/c-export-measured.md gives
its accuracy and speed); float32 keeps libm's ``expf``.
"""

from string import Template

__all__ = ["EXP_BLOCK_F64", "EXP_BLOCK_LIBM"]

# exp of one block, float64: Cody-Waite reduction x = n ln2 + r (|r| <= ln2/2), the degree-12
# Taylor polynomial of exp(r) (truncation < 2e-16) and 2^n from the exponent bits (memcpy: no
# aliasing, inlined by the compiler).  Relative error <= 4.5e-16 (2 ulp) against libm on 1e7
# points of [-708, 709].  No branch in the loop and a fixed trip count, so gcc vectorizes it at
# -O2; n outside [-1022, 1023] (x below about -708 or above 709, +-inf, NaN) is flagged with
# integer operations only, and such a block is recomputed with libm's exp.
EXP_BLOCK_F64 = Template(r"""static void ${p}_exp_block(const double *restrict x, double *restrict k)
{
    int j;
    uint64_t bad = 0;
    for (j = 0; j < ${P}_BLOCK; ++j) {
        double t = x[j] * 1.4426950408889634 + 6755399441055744.0;   /* 1.5 * 2^52: rounds x/ln2 */
        double n = t - 6755399441055744.0, s, p, r;
        uint64_t bits, m;
        memcpy(&bits, &t, sizeof bits);                 /* 0x4338000000000000 + n */
        r = (x[j] - n * 0.6931471803691238) - n * 1.9082149292705877e-10;
        p = 1.0 / 479001600.0;
        p = p * r + 1.0 / 39916800.0;
        p = p * r + 1.0 / 3628800.0;
        p = p * r + 1.0 / 362880.0;
        p = p * r + 1.0 / 40320.0;
        p = p * r + 1.0 / 5040.0;
        p = p * r + 1.0 / 720.0;
        p = p * r + 1.0 / 120.0;
        p = p * r + 1.0 / 24.0;
        p = p * r + 1.0 / 6.0;
        p = p * r + 0.5;
        p = p * r + 1.0;
        p = p * r + 1.0;
        m = bits - UINT64_C(0x4338000000000000) + 1022;    /* n + 1022: valid in [0, 2045] */
        bad |= (m >> 11) | ((m + 2) >> 11);
        bits = (bits + 1023) << 52;                     /* 2^n */
        memcpy(&s, &bits, sizeof s);
        k[j] = p * s;
    }
    if (bad)
        for (j = 0; j < ${P}_BLOCK; ++j) k[j] = exp(x[j]);
}
""")

# exp of one block with libm (float32: expf).
EXP_BLOCK_LIBM = Template(r"""static void ${p}_exp_block(const $real *restrict x, $real *restrict k)
{
    int j;
    for (j = 0; j < ${P}_BLOCK; ++j) k[j] = $exp(x[j]);
}
""")
