/* Times Siconos' lexicographic Lemke (lcp_lexicolemke) from C, with no interpreter between the
 * clock and the call: the other side of the table of docs/backends.md#lemke-speed.
 *
 * Not part of the build or the tests. Needs Debian's Siconos headers and library:
 *
 *     apt-get install -y libsiconos-numerics-dev
 *     cc -O2 -o target/siconos_lemke benches/siconos_lemke.c -I/usr/include/siconos/numerics \
 *         -I/usr/include/siconos -lsiconos_numerics
 *     python3 benches/lcp_to_text.py target/lcp/lcp_n10.json > target/lcp/lcp_n10.txt
 *     target/siconos_lemke target/lcp/lcp_n10.txt 1000
 *
 * The text file is n, then M by rows, then q (whitespace-separated). Prints one JSON line:
 * {"file", "n", "info", "pivots", "best_us", "median_us", "residual", "z"}: best and median of
 * N warm solves (the first solve is not timed), each timed around the call with
 * clock_gettime(CLOCK_MONOTONIC); "z" in 17 significant digits.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "LCP_Solvers.h"
#include "LinearComplementarityProblem.h"
#include "NumericsMatrix.h"
#include "SolverOptions.h"
#include "lcp_cst.h"

static double now_us(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec * 1e6 + (double)t.tv_nsec * 1e-3;
}

static int cmp(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

int main(int argc, char **argv) {
  if (argc < 3) {
    fprintf(stderr, "usage: %s FILE.txt REPEAT\n", argv[0]);
    return 2;
  }
  FILE *f = fopen(argv[1], "r");
  int n;
  if (!f || fscanf(f, "%d", &n) != 1 || n <= 0) {
    fprintf(stderr, "cannot read %s\n", argv[1]);
    return 2;
  }
  int repeat = atoi(argv[2]);
  if (repeat <= 0) repeat = 1;
  double *m = malloc(sizeof(double) * n * n); /* column-major, as Siconos' dense storage */
  double *q = malloc(sizeof(double) * n);
  for (int i = 0; i < n; i++)
    for (int j = 0; j < n; j++)
      if (fscanf(f, "%lf", &m[j * n + i]) != 1) return 2;
  for (int i = 0; i < n; i++)
    if (fscanf(f, "%lf", &q[i]) != 1) return 2;
  fclose(f);
  LinearComplementarityProblem lcp = {n, NM_create_from_data(NM_DENSE, n, n, m), q};
  SolverOptions *options = solver_options_create(SICONOS_LCP_LEMKE);
  double *z = calloc(n, sizeof(double)), *w = calloc(n, sizeof(double));
  double *times = malloc(sizeof(double) * repeat);
  int info = 0;
  lcp_lexicolemke(&lcp, z, w, &info, options); /* first (cold) solve */
  int pivots = options->iparam[1];
  for (int r = 0; r < repeat; r++) {
    double t0 = now_us();
    lcp_lexicolemke(&lcp, z, w, &info, options);
    times[r] = now_us() - t0;
  }
  qsort(times, repeat, sizeof(double), cmp);
  double residual = 0.0;
  for (int i = 0; i < n; i++) {
    double wi = q[i];
    for (int j = 0; j < n; j++) wi += m[j * n + i] * z[j];
    residual = fmax(residual, fabs(fmin(z[i], wi)));
  }
  printf("{\"file\": \"%s\", \"n\": %d, \"info\": %d, \"pivots\": %d, \"best_us\": %.3f, "
         "\"median_us\": %.3f, \"residual\": %.3e, \"z\": [",
         argv[1], n, info, pivots, times[0], times[repeat / 2], residual);
  for (int i = 0; i < n; i++) printf("%s%.17g", i ? ", " : "", z[i]);
  printf("]}\n");
  return 0;
}
