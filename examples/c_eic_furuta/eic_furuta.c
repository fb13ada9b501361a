/* eic_furuta.c: see eic_furuta.h. */
#include <math.h>
#include <stddef.h>
#include "bem_predictor.h"
#include "eic_furuta.h"

static const double EIC_TWO_PI = 6.283185307179586;

/* theta_d and its first two derivatives at t */
static void eic_reference_at(const eic_reference *r, double t, double *q, double *qd, double *qdd)
{
    int k;
    *q = r->offset;
    *qd = *qdd = 0.0;
    for (k = 0; k < r->n; ++k) {
        double w = EIC_TWO_PI * r->frequency_hz[k], s = sin(w * t + r->phase[k]), c = cos(w * t + r->phase[k]);
        *q += r->amplitude[k] * s;
        *qd += r->amplitude[k] * w * c;
        *qdd -= r->amplitude[k] * w * w * s;
    }
}

/* the BEM along the reference: bem_mean([qdd_d, qd_d, q_d](t)) */
static double eic_bem_on_reference(const eic_reference *r, double t)
{
    double x[3];
    eic_reference_at(r, t, &x[2], &x[1], &x[0]);
    return bem_mean(x);
}

double eic_furuta_command(const eic_furuta_params *p, const eic_gains *g, const eic_reference *r,
                          double t, const double *q, const double *qd, eic_info *info)
{
    double qa_d, qad_d, qadd_d, b0, b1, b2, h = g->deriv_step;
    double v_ext, alphad_e, alphadd_e, alpha_e, v_u, s, c, daa, dau, ha, hu, v_a, tau, volts;
    eic_reference_at(r, t, &qa_d, &qad_d, &qadd_d);
    v_ext = qadd_d - g->kd_a * (qd[0] - qad_d) - g->kp_a * (q[0] - qa_d);
    b0 = eic_bem_on_reference(r, t - h);
    b1 = eic_bem_on_reference(r, t);
    b2 = eic_bem_on_reference(r, t + h);
    alphad_e = (b2 - b0) / (2.0 * h);
    alphadd_e = (b2 - 2.0 * b1 + b0) / (h * h);
    if (g->momentum_correction) {
        double xf[5];
        xf[0] = v_ext; xf[1] = qd[0]; xf[2] = q[0]; xf[3] = alphadd_e; xf[4] = alphad_e;
        alpha_e = bem_full_mean(xf);
    } else {
        double x[3];
        x[0] = v_ext; x[1] = qd[0]; x[2] = q[0];
        alpha_e = bem_mean(x);
    }
    v_u = alphadd_e - g->kd_u * (qd[1] - alphad_e) - g->kp_u * (q[1] - alpha_e);
    s = sin(q[1]);
    c = cos(q[1]);
    daa = p->Daa0 + p->sin2 * s * s + p->cos2 * c * c;
    dau = -p->mLl * c;
    ha = 2.0 * (p->sin2 - p->cos2) * s * c * qd[0] * qd[1] + p->mLl * s * qd[1] * qd[1] + p->B_r * qd[0];
    hu = -(p->sin2 - p->cos2) * s * c * qd[0] * qd[0] - p->mgl * s + p->B_p * qd[1];
    v_a = -(p->Duu * v_u + hu) / dau;                  /* eq. (8), m = 1 */
    tau = daa * v_a + dau * v_u + ha;                  /* eq. (3) */
    volts = (tau + p->b_emf * qd[0]) / p->k_u;
    if (volts > p->V_max) volts = p->V_max;
    if (volts < -p->V_max) volts = -p->V_max;
    if (info != NULL) {
        info->alpha_e = alpha_e; info->alphad_e = alphad_e; info->alphadd_e = alphadd_e;
        info->v_ext = v_ext; info->v_u = v_u; info->tau = tau;
    }
    return volts;
}
