// bench/ba peer driver: bundle adjustment of a BAL problem with Ceres (Debian libceres-dev).
//
// The model is the BAL/Snavely reprojection error of Ceres's own bundle_adjuster example
// (9 camera parameters: angle-axis, translation, f, k1, k2; 3 per point; autodiff), so the cost
// ½Σ‖ẑ − z‖² is exactly dwslam's. Observations whose point is behind its camera at the initial
// values (P_z ≥ 0 in the BAL frame, which looks down −z) are left out, as dwslam does.
//
// usage: ceres_ba FILE --iterations N --threads T --solver sparse_schur|iterative_schur
//                  [--preconditioner jacobi|schur_jacobi] [--json OUT]
// Prints one line per iteration (cost, time) and, with --json, a summary.
#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <chrono>
#include <ctime>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

struct Bal {
  int num_cameras = 0, num_points = 0, num_observations = 0;
  std::vector<int> camera_index, point_index;
  std::vector<double> observations, cameras, points;
};

static bool read_bal(const char* path, Bal* bal) {
  FILE* f = std::fopen(path, "r");
  if (!f) return false;
  if (std::fscanf(f, "%d %d %d", &bal->num_cameras, &bal->num_points, &bal->num_observations) != 3) return false;
  bal->camera_index.resize(bal->num_observations);
  bal->point_index.resize(bal->num_observations);
  bal->observations.resize(2 * bal->num_observations);
  for (int i = 0; i < bal->num_observations; ++i) {
    if (std::fscanf(f, "%d %d %lf %lf", &bal->camera_index[i], &bal->point_index[i], &bal->observations[2 * i],
                    &bal->observations[2 * i + 1]) != 4)
      return false;
  }
  bal->cameras.resize(9 * bal->num_cameras);
  for (double& v : bal->cameras)
    if (std::fscanf(f, "%lf", &v) != 1) return false;
  bal->points.resize(3 * bal->num_points);
  for (double& v : bal->points)
    if (std::fscanf(f, "%lf", &v) != 1) return false;
  std::fclose(f);
  return true;
}

struct SnavelyReprojectionError {
  SnavelyReprojectionError(double x, double y) : observed_x(x), observed_y(y) {}
  template <typename T>
  bool operator()(const T* const camera, const T* const point, T* residuals) const {
    T p[3];
    ceres::AngleAxisRotatePoint(camera, point, p);
    p[0] += camera[3];
    p[1] += camera[4];
    p[2] += camera[5];
    T xp = -p[0] / p[2];
    T yp = -p[1] / p[2];
    const T& l1 = camera[7];
    const T& l2 = camera[8];
    T r2 = xp * xp + yp * yp;
    T distortion = 1.0 + r2 * (l1 + l2 * r2);
    const T& focal = camera[6];
    residuals[0] = focal * distortion * xp - observed_x;
    residuals[1] = focal * distortion * yp - observed_y;
    return true;
  }
  double observed_x, observed_y;
};

struct Timer : public ceres::IterationCallback {
  std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
  std::vector<double> cost, elapsed;
  std::vector<int> successful;
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& s) override {
    double t = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    cost.push_back(s.cost);
    elapsed.push_back(t);
    successful.push_back(s.step_is_successful ? 1 : 0);
    std::printf("%4d  %16.6f  %9.2e  %6s  %6d  %9.3f\n", s.iteration, s.cost, 1.0 / s.trust_region_radius,
                s.step_is_successful ? "taken" : "reject", s.linear_solver_iterations, t);
    return ceres::SOLVER_CONTINUE;
  }
};

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s FILE --iterations N --threads T --solver sparse_schur|iterative_schur [--preconditioner jacobi|schur_jacobi] [--json OUT]\n", argv[0]);
    return 2;
  }
  const char* path = argv[1];
  int iterations = 10, threads = 1;
  std::string solver = "sparse_schur", preconditioner = "schur_jacobi", json;
  for (int i = 2; i + 1 < argc; i += 2) {
    if (!std::strcmp(argv[i], "--iterations")) iterations = std::atoi(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--threads")) threads = std::atoi(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--solver")) solver = argv[i + 1];
    else if (!std::strcmp(argv[i], "--preconditioner")) preconditioner = argv[i + 1];
    else if (!std::strcmp(argv[i], "--json")) json = argv[i + 1];
    else { std::fprintf(stderr, "unknown option %s\n", argv[i]); return 2; }
  }
  Bal bal;
  if (!read_bal(path, &bal)) { std::fprintf(stderr, "cannot read %s\n", path); return 1; }

  ceres::Problem problem;
  int used = 0, rejected = 0;
  for (int i = 0; i < bal.num_observations; ++i) {
    double* camera = &bal.cameras[9 * bal.camera_index[i]];
    double* point = &bal.points[3 * bal.point_index[i]];
    double p[3];
    ceres::AngleAxisRotatePoint(camera, point, p);
    if (p[2] + camera[5] >= -1e-9) { ++rejected; continue; }  // behind the camera
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<SnavelyReprojectionError, 2, 9, 3>(
                                 new SnavelyReprojectionError(bal.observations[2 * i], bal.observations[2 * i + 1])),
                             nullptr, camera, point);
    ++used;
  }
  ceres::Solver::Options options;
  options.minimizer_type = ceres::TRUST_REGION;
  options.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  options.linear_solver_type = solver == "iterative_schur" ? ceres::ITERATIVE_SCHUR : ceres::SPARSE_SCHUR;
  options.preconditioner_type = preconditioner == "jacobi" ? ceres::JACOBI : ceres::SCHUR_JACOBI;
  options.max_num_iterations = iterations;
  options.num_threads = threads;
  options.function_tolerance = 0.0;  // run exactly the given number of iterations
  options.gradient_tolerance = 0.0;
  options.parameter_tolerance = 0.0;
  options.minimizer_progress_to_stdout = false;
  // Points first in the elimination order, as Ceres's bundle_adjuster does.
  auto* ordering = new ceres::ParameterBlockOrdering;
  for (int j = 0; j < bal.num_points; ++j)
    if (problem.HasParameterBlock(&bal.points[3 * j])) ordering->AddElementToGroup(&bal.points[3 * j], 0);
  for (int c = 0; c < bal.num_cameras; ++c)
    if (problem.HasParameterBlock(&bal.cameras[9 * c])) ordering->AddElementToGroup(&bal.cameras[9 * c], 1);
  options.linear_solver_ordering.reset(ordering);
  Timer timer;
  options.callbacks.push_back(&timer);
  options.update_state_every_iteration = false;
  std::printf("ceres %s: %d cameras, %d points, %d observations (%d behind their camera left out), %d thread(s), %s/%s\n",
              path, bal.num_cameras, bal.num_points, used, rejected, threads, solver.c_str(), preconditioner.c_str());
  std::printf("iter  %16s  %9s  %6s  %6s  %9s\n", "½Σ‖r‖²", "λ", "step", "lin.it", "total s");
  timer.start = std::chrono::steady_clock::now();
  ceres::Solver::Summary summary;
  std::clock_t cpu_start = std::clock();
  ceres::Solve(options, &problem, &summary);
  double cpu_seconds = double(std::clock() - cpu_start) / CLOCKS_PER_SEC;
  if (summary.termination_type == ceres::FAILURE && summary.iterations.empty()) {
    std::fprintf(stderr, "ceres refused to solve: %s\n", summary.message.c_str());
    return 1;
  }
  double time_min = summary.minimizer_time_in_seconds;
  int n = summary.iterations.size() - 1;  // iteration 0 is the initial evaluation
  std::printf("initial ½Σ‖r‖² = %.6f, final = %.6f, %d iterations, minimizer %.3f s (%.4f s/iteration), total %.3f s\n",
              summary.initial_cost, summary.final_cost, n, time_min, n > 0 ? time_min / n : 0.0, summary.total_time_in_seconds);
  if (!json.empty()) {
    std::ofstream out(json);
    out.precision(17);
    out << "{\"initial_cost\": " << summary.initial_cost << ", \"final_cost\": " << summary.final_cost
        << ", \"iterations\": " << n << ", \"minimizer_time_s\": " << time_min
        << ", \"time_per_iteration_s\": " << (n > 0 ? time_min / n : 0.0)
        << ", \"cpu_time_per_iteration_s\": " << (n > 0 ? cpu_seconds / n : 0.0)
        << ", \"total_time_s\": " << summary.total_time_in_seconds << ", \"observations\": " << used
        << ", \"rejected_observations\": " << rejected << ", \"threads\": " << threads
        << ", \"solver\": \"" << solver << "\", \"preconditioner\": \"" << preconditioner << "\", \"per_iteration\": [";
    for (size_t k = 0; k < timer.cost.size(); ++k)
      out << (k ? ", " : "") << "{\"cost\": " << timer.cost[k] << ", \"elapsed_s\": " << timer.elapsed[k]
          << ", \"accepted\": " << (timer.successful[k] ? "true" : "false") << "}";
    out << "]}\n";
  }
  return 0;
}
