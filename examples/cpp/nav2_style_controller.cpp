// A local controller shaped like a Nav2 controller plugin (nav2_core::Controller): configure,
// setPlan, computeVelocityCommands(pose, velocity) returning a twist, written on the planner's
// C API. A ROS 2 node wraps it by converting messages (README, "Using the planner from ROS 2"):
// nav_msgs/Path -> setPlan, a people/tracks message -> setPeople, geometry_msgs/PoseStamped and
// Twist -> computeVelocityCommands, and the returned twist -> geometry_msgs/TwistStamped.
//
// main() drives it in a small closed loop: the robot follows a straight 8 m path while one
// pedestrian walks towards it and another crosses, and the program reports whether the robot
// reached the end of the path and how close it came to the people.
//
// Build and run from the repository root after `cargo build -p human2nav-capi` (`sdk/dev.sh
// test` does all this for you):
//   c++ -std=c++17 -I sdk/capi/include examples/cpp/nav2_style_controller.cpp
//       -L target/debug -lhuman2nav_c -Wl,-rpath,target/debug -o controller   (one line)
//   ./controller robots/diablo/robot.toml sdk/configs/planner.toml models/human2nav-cfm
#include <cmath>
#include <cstdio>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "human2nav.h"

namespace h2n {

// Throws the library's message when a call fails.
void check(h2n_status status, const char* what) {
    if (status != H2N_STATUS_OK) {
        throw std::runtime_error(std::string(what) + ": " + h2n_last_error());
    }
}

struct PlannerFree {
    void operator()(h2n_planner* p) const { h2n_planner_free(p); }
};
struct PlanFree {
    void operator()(h2n_plan* p) const { h2n_plan_free(p); }
};

class Human2NavController {
public:
    // Loads the robot, the planner configuration and the model. `replan_period` is how often
    // a new plan is made (s); `budget_ms` bounds each planning call (0: none).
    void configure(const std::string& robot_toml, const std::string& planner_toml,
                   const std::string& model_dir, double replan_period = 0.1,
                   double budget_ms = 0.0) {
        h2n_planner* raw = nullptr;
        check(h2n_planner_create(robot_toml.c_str(), planner_toml.c_str(), model_dir.c_str(),
                                 &raw),
              "h2n_planner_create");
        planner_.reset(raw);
        replan_period_ = replan_period;
        budget_ms_ = budget_ms;
    }

    // The global path to follow (world frame); the planner aims at the path's pose
    // `lookahead` metres ahead of the robot, the end of the path at the latest.
    void setPlan(const std::vector<h2n_pose>& path) {
        if (path.empty()) {
            throw std::invalid_argument("setPlan: the path is empty");
        }
        path_ = path;
        progress_ = 0;
        plan_.reset();
        check(h2n_planner_reset(planner_.get()), "h2n_planner_reset");
    }

    // The people around the robot (world frame), e.g. from a tracker.
    void setPeople(const std::vector<h2n_agent>& people) { people_ = people; }

    // The velocity command for the robot at `pose` (world frame) moving at `velocity` (body
    // frame) at time `now` (s).
    h2n_twist computeVelocityCommands(const h2n_pose& pose, const h2n_twist& velocity,
                                      double now) {
        if (!plan_ || now - plan_time_ >= replan_period_ - 1e-9) {
            replan(pose, velocity, now);
        }
        h2n_twist cmd{};
        check(h2n_planner_command(planner_.get(), plan_.get(), now + control_dt_, pose,
                                  velocity, control_dt_, &cmd),
              "h2n_planner_command");
        return cmd;
    }

    // The last plan's diagnostics.
    h2n_plan_info lastPlanInfo() const {
        h2n_plan_info info{};
        check(h2n_plan_get_info(plan_.get(), &info), "h2n_plan_get_info");
        return info;
    }

private:
    void replan(const h2n_pose& pose, const h2n_twist& velocity, double now) {
        const h2n_pose goal = goalOnPath(pose);
        h2n_observation obs{};
        obs.time = now;
        obs.ego = pose;
        obs.ego_velocity = velocity;
        obs.goal_x = goal.x;
        obs.goal_y = goal.y;
        obs.agents = people_.data();
        obs.agent_count = people_.size();
        h2n_plan* raw = nullptr;
        check(h2n_planner_plan(planner_.get(), &obs, budget_ms_, &raw), "h2n_planner_plan");
        plan_.reset(raw);
        plan_time_ = now;
    }

    // The path pose `lookahead_` metres (along the path) past the one closest to the robot.
    h2n_pose goalOnPath(const h2n_pose& pose) {
        auto dist = [](const h2n_pose& a, const h2n_pose& b) {
            return std::hypot(a.x - b.x, a.y - b.y);
        };
        for (size_t i = progress_; i < path_.size(); ++i) {
            if (dist(path_[i], pose) < dist(path_[progress_], pose)) {
                progress_ = i;
            }
        }
        double along = 0.0;
        size_t i = progress_;
        while (i + 1 < path_.size() && along < lookahead_) {
            along += dist(path_[i], path_[i + 1]);
            ++i;
        }
        return path_[i];
    }

    std::unique_ptr<h2n_planner, PlannerFree> planner_;
    std::unique_ptr<h2n_plan, PlanFree> plan_;
    std::vector<h2n_pose> path_;
    std::vector<h2n_agent> people_;
    size_t progress_ = 0;
    double plan_time_ = 0.0;
    double replan_period_ = 0.1;
    double budget_ms_ = 0.0;
    double control_dt_ = 0.1;
    double lookahead_ = 5.0;
};

}  // namespace h2n

int main(int argc, char** argv) {
    if (argc != 4) {
        std::fprintf(stderr, "usage: %s <robot.toml> <planner.toml> <model folder>\n", argv[0]);
        return 2;
    }
    try {
        h2n::Human2NavController controller;
        controller.configure(argv[1], argv[2], argv[3]);

        std::vector<h2n_pose> path;
        for (int k = 0; k <= 16; ++k) {
            path.push_back({0.5 * k, 0.0, 0.0});
        }
        controller.setPlan(path);
        const h2n_pose goal = path.back();

        std::vector<h2n_agent> people = {
            {1, 6.0, 0.2, -0.8, 0.0, 0.3},   // walking towards the robot
            {2, 4.0, -3.0, 0.0, 0.7, 0.3},   // crossing its path
        };
        h2n_pose pose{0.0, 0.0, 0.0};
        h2n_twist velocity{0.0, 0.0, 0.0};
        const double dt = 0.1;
        double closest = INFINITY;
        double t = 0.0;
        bool reached = false;
        for (int step = 0; step < 300 && !reached; ++step) {
            controller.setPeople(people);
            const h2n_twist cmd = controller.computeVelocityCommands(pose, velocity, t);
            // The robot executes the command for one period (a unicycle with sideways speed).
            const double c = std::cos(pose.theta), s = std::sin(pose.theta);
            pose.x += (cmd.vx * c - cmd.vy * s) * dt;
            pose.y += (cmd.vx * s + cmd.vy * c) * dt;
            pose.theta += cmd.omega * dt;
            velocity = cmd;
            t += dt;
            for (auto& p : people) {
                p.x += p.vx * dt;
                p.y += p.vy * dt;
                closest = std::fmin(closest, std::hypot(p.x - pose.x, p.y - pose.y));
            }
            reached = std::hypot(goal.x - pose.x, goal.y - pose.y) < 0.3;
        }
        const h2n_plan_info info = controller.lastPlanInfo();
        std::printf("last plan: %zu poses, fallback %s\n", info.pose_count,
                    info.fallback ? "yes" : "no");
        std::printf("%s after %.1f s at (%.2f, %.2f); closest pedestrian %.2f m centre to "
                    "centre\n",
                    reached ? "reached the end of the path" : "did NOT reach the end of the path",
                    t, pose.x, pose.y, closest);
        return reached ? 0 : 1;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "error: %s\n", e.what());
        return 1;
    }
}
