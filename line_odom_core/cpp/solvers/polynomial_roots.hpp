// Real roots of cubic and quartic polynomials in closed form (Cardano / Ferrari), double precision, polished
// by Newton steps, no allocation. Hand-written because Eigen's PolynomialSolver (unsupported module) goes
// through a companion-matrix eigen decomposition, about 10x slower than the closed form for a quartic.
#pragma once

#include <cmath>

namespace line_odom {
namespace polynomial_roots {

// Evaluates c[0] x^n + c[1] x^(n-1) + ... + c[n] and its derivative.
template <int N>
inline void evaluate(const double* c, double x, double* value, double* derivative) {
  double p = c[0], dp = 0.0;
  for (int i = 1; i <= N; ++i) {
    dp = dp * x + p;
    p = p * x + c[i];
  }
  *value = p;
  *derivative = dp;
}

// Newton steps that are kept only while they reduce |p(x)|.
template <int N>
inline double polish(const double* c, double x, int steps) {
  double f, df;
  evaluate<N>(c, x, &f, &df);
  for (int i = 0; i < steps; ++i) {
    if (f == 0.0 || df == 0.0) break;
    const double x_new = x - f / df;
    double f_new, df_new;
    evaluate<N>(c, x_new, &f_new, &df_new);
    if (!(std::abs(f_new) < std::abs(f))) break;
    x = x_new;
    f = f_new;
    df = df_new;
  }
  return x;
}

// Largest real root of the monic cubic x^3 + a x^2 + b x + c.
inline double largest_cubic_root(double a, double b, double c) {
  const double a3 = a / 3.0;
  const double P = b - a * a3;                                  // depressed y^3 + P y + Q, x = y - a/3
  const double Q = 2.0 * a3 * a3 * a3 - a3 * b + c;
  const double half_q = 0.5 * Q, third_p = P / 3.0;
  const double disc = half_q * half_q + third_p * third_p * third_p;
  double y;
  if (disc > 0.0) {  // one real root
    const double sq = std::sqrt(disc);
    const double u = std::cbrt(half_q > 0.0 ? -half_q - sq : -half_q + sq);
    y = (u != 0.0) ? u - third_p / u : 0.0;
  } else {  // three real roots (third_p <= 0): the largest is k = 0 of the trigonometric form
    const double r = std::sqrt(-third_p);
    double arg = (r > 0.0) ? -half_q / (r * r * r) : 0.0;
    arg = arg > 1.0 ? 1.0 : (arg < -1.0 ? -1.0 : arg);
    y = 2.0 * r * std::cos(std::acos(arg) / 3.0);
  }
  const double coeffs[4] = {1.0, a, b, c};
  return polish<3>(coeffs, y - a3, 2);
}

// Real roots of x^2 + b x + c appended to roots; returns the new count.
inline int monic_quadratic_roots(double b, double c, double* roots, int count) {
  const double disc = b * b - 4.0 * c;
  if (disc < 0.0) return count;
  const double sq = std::sqrt(disc);
  const double q = -0.5 * (b + (b >= 0.0 ? sq : -sq));
  if (q != 0.0) {
    roots[count++] = q;
    roots[count++] = c / q;
  } else {
    roots[count++] = 0.0;  // b = c = 0
  }
  return count;
}

// Real roots of c[0] x^4 + c[1] x^3 + c[2] x^2 + c[3] x + c[4] with c[0] != 0 (Ferrari), each polished by
// Newton steps on the original polynomial. Returns the number of roots written (<= 4), duplicates possible.
inline int quartic_roots(const double* c, double* roots) {
  if (!(c[0] != 0.0) || !std::isfinite(c[0])) return 0;
  const double a = c[1] / c[0], b = c[2] / c[0], cc = c[3] / c[0], d = c[4] / c[0];
  // depressed y^4 + p y^2 + q y + r with x = y - a/4
  const double a2 = a * a;
  const double p = b - 0.375 * a2;
  const double q = cc - 0.5 * a * b + 0.125 * a2 * a;
  const double r = d - 0.25 * a * cc + 0.0625 * a2 * b - 3.0 / 256.0 * a2 * a2;
  double y[4];
  int n = 0;
  const double scale = 1.0 + std::abs(p) + std::sqrt(std::abs(r));
  if (std::abs(q) <= 1e-14 * scale * scale * scale) {  // biquadratic: z^2 + p z + r with z = y^2
    double z[2];
    const int nz = monic_quadratic_roots(p, r, z, 0);
    for (int i = 0; i < nz; ++i) {
      if (z[i] >= 0.0) {
        const double s = std::sqrt(z[i]);
        y[n++] = s;
        y[n++] = -s;
      }
    }
  } else {
    // (y^2 + p/2 + m)^2 = 2m (y - q/(4m))^2 where m > 0 solves 8m^3 + 8p m^2 + (2p^2 - 8r) m - q^2 = 0
    const double m = largest_cubic_root(p, 0.25 * p * p - r, -0.125 * q * q);
    if (!(m > 0.0)) return 0;
    const double s = std::sqrt(2.0 * m);
    const double k = q / (2.0 * s);  // = s q / (4m)
    n = monic_quadratic_roots(-s, 0.5 * p + m + k, y, n);
    n = monic_quadratic_roots(s, 0.5 * p + m - k, y, n);
  }
  for (int i = 0; i < n; ++i) roots[i] = polish<4>(c, y[i] - 0.25 * a, 3);
  return n;
}

}  // namespace polynomial_roots
}  // namespace line_odom
