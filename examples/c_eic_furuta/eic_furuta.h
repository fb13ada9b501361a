/* eic_furuta.h: the EIC balance controller (paper eq. 3 and 8) for the Furuta pendulum in C99,
 * with the learned BEM of `bemlearn export RUN_DIR --format c` (bem_predictor.h/.c) in the loop.
 *
 * Per control tick, q = [theta, alpha] (rad, measured), qd (rad/s, estimated), t (s):
 *   1. external loop   v_ext = qdd_d - kd_a (qd_theta - qd_d) - kp_a (theta - q_d)
 *   2. BEM             alpha_e = bem_mean([v_ext, qd_theta, theta])            (eq. 14)
 *                      or, with momentum correction, bem_full_mean([v_ext, qd_theta, theta,
 *                      alphadd_e, alphad_e])  (eq. 11); the BEM rates alphad_e, alphadd_e are
 *                      central differences of bem_mean along the reference at t - h, t, t + h
 *   3. internal loop   v_u = alphadd_e - kd_u (qd_alpha - alphad_e) - kp_u (alpha - alpha_e)
 *   4. eq. (8), m = 1: v_a = -(D_uu v_u + h_u) / D_ua
 *   5. eq. (3)         tau = D_aa v_a + D_au v_u + h_a, and the Quanser motor inverse
 *                      V = (tau + b_emf qd_theta) / k_u clipped to +-V_max (volts)
 * D, h are the analytic rigid-body Furuta rows (bemlearn/robots/furuta.py, AnalyticFuruta).
 * Same law as bemlearn.control.eic.EICController.  No heap, no static state: reentrant.
 */
#ifndef EIC_FURUTA_H
#define EIC_FURUTA_H

#define EIC_MAX_SINES 8

typedef struct {
    double Daa0;   /* J_r + m_p L_r^2, kg m^2 */
    double sin2;   /* coefficient of sin^2(alpha) in D_aa: J_p + m_p l^2 */
    double cos2;   /* coefficient of cos^2(alpha) in D_aa: J_ax */
    double mLl;    /* m_p L_r l, kg m^2 */
    double Duu;    /* J_p + m_p l^2, kg m^2 */
    double mgl;    /* m_p g l, N m */
    double B_r, B_p;            /* viscous damping, N m s/rad */
    double k_u, b_emf, V_max;   /* motor: N m/V, N m s/rad, V */
} eic_furuta_params;

typedef struct {
    double kp_a, kd_a;          /* external loop, 1/s^2, 1/s */
    double kp_u, kd_u;          /* internal loop, 1/s^2, 1/s */
    double deriv_step;          /* h of the BEM rates along the reference, s */
    int momentum_correction;    /* 1: evaluate the full map at the BEM's own rates */
} eic_gains;

typedef struct {                /* theta_d(t) = offset + sum_k A_k sin(2 pi f_k t + phi_k) */
    int n;
    double amplitude[EIC_MAX_SINES], frequency_hz[EIC_MAX_SINES], phase[EIC_MAX_SINES];
    double offset;
} eic_reference;

typedef struct {                /* what one tick computed (for logging) */
    double alpha_e, alphad_e, alphadd_e, v_ext, v_u, tau;
} eic_info;

/* Motor voltage (V) for time t (s), q = [theta, alpha] (rad), qd (rad/s); info may be NULL. */
double eic_furuta_command(const eic_furuta_params *p, const eic_gains *g, const eic_reference *r,
                          double t, const double *q, const double *qd, eic_info *info);

#endif
