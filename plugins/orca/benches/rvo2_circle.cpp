// RVO2's side of the ORCA speed comparison (ARCHITECTURE.md, "ORCA crowds and their neighbour
// index"): the Circle scenario of the `orca/circle_n<N>` criterion bench (benches/orca.rs),
// driven through RVO2's own simulator, timed per agent-step.
//
// RVO2 (https://github.com/snape/RVO2, Apache-2.0) is not part of this repository. With a
// checkout of it in $RVO2 (the comparison used commit 1c25b27):
//
//   # the library compiled file by file, as its CMake build does
//   for f in Agent KdTree Obstacle RVOSimulator Vector2 Line; do
//     g++ -O3 -march=native -std=c++17 -I"$RVO2/src" -c "$RVO2/src/$f.cc" -o "$f.o"; done
//   g++ -O3 -march=native -std=c++17 -I"$RVO2/src" rvo2_circle.cpp *.o -o rvo2_circle
//   # and with link-time optimisation, which inlines RVO2's out-of-line vector operators
//   g++ -O3 -march=native -flto -std=c++17 -I"$RVO2/src" rvo2_circle.cpp "$RVO2"/src/*.cc \
//       -o rvo2_circle_lto
//   ./rvo2_circle 5 1001; ./rvo2_circle 100 1001; ./rvo2_circle 1000 3
//
// Arguments: the number of agents N and the number of repeats; prints the median wall time
// per agent-step. Scenario (as in benches/orca.rs): N agents evenly spaced on a circle of
// radius max(10, 4N/2π) m heading for their antipodes; radius 1.5 m, max speed 2 m/s,
// neighbour distance 15 m, 10 neighbours, time horizons 5 s, time step 0.25 s; each step the
// preferred velocity is the goal vector clipped to unit length plus a perturbation of at most
// 0.01 m/s per axis from the same 64-bit LCG; ceil(8ρ) steps from the start. Only the steps
// are timed, not building the simulator.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include "RVO.h"

namespace {

// Knuth's MMIX LCG, uniform in [0, 1): the bench's perturbation stream.
struct Lcg {
  uint64_t state;
  double uniform() {
    state = state * 6364136223846793005ULL + 1442695040888963407ULL;
    return static_cast<double>(state >> 11) / static_cast<double>(1ULL << 53);
  }
};

}  // namespace

int main(int argc, char **argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: %s <agents> <repeats>\n", argv[0]);
    return 2;
  }
  const int n = std::atoi(argv[1]);
  const int repeats = std::atoi(argv[2]);
  if (n < 1 || repeats < 1) {
    std::fprintf(stderr, "agents and repeats must be positive integers\n");
    return 2;
  }
  const double tau = 6.283185307179586;
  const double rho = std::max(10.0, 4.0 * n / tau);
  const int steps = static_cast<int>(std::ceil(8.0 * rho));
  std::vector<double> seconds;
  float checksum = 0.0f;
  for (int r = 0; r < repeats; ++r) {
    RVO::RVOSimulator sim;
    sim.setTimeStep(0.25f);
    sim.setAgentDefaults(15.0f, 10, 5.0f, 5.0f, 1.5f, 2.0f);
    std::vector<RVO::Vector2> goals;
    for (int i = 0; i < n; ++i) {
      const double a = tau * i / n;
      const RVO::Vector2 p(static_cast<float>(rho * std::cos(a)),
                           static_cast<float>(rho * std::sin(a)));
      sim.addAgent(p);
      goals.push_back(-p);
    }
    Lcg rng{1};
    const auto start = std::chrono::steady_clock::now();
    for (int s = 0; s < steps; ++s) {
      for (int i = 0; i < n; ++i) {
        RVO::Vector2 to_goal = goals[i] - sim.getAgentPosition(i);
        if (RVO::absSq(to_goal) > 1.0f) to_goal = RVO::normalize(to_goal);
        const float jx = static_cast<float>((rng.uniform() - 0.5) * 0.02);
        const float jy = static_cast<float>((rng.uniform() - 0.5) * 0.02);
        sim.setAgentPrefVelocity(i, to_goal + RVO::Vector2(jx, jy));
      }
      sim.doStep();
    }
    const auto end = std::chrono::steady_clock::now();
    seconds.push_back(std::chrono::duration<double>(end - start).count());
    checksum += sim.getAgentPosition(0).x();  // keeps the work observable
  }
  std::sort(seconds.begin(), seconds.end());
  const double median = seconds[seconds.size() / 2];
  std::printf("rvo2 circle_n%d: %d steps x %d agents, median of %d: %.3f us per agent-step"
              " (checksum %g)\n",
              n, steps, n, repeats, median * 1e6 / (static_cast<double>(steps) * n), checksum);
  return 0;
}
