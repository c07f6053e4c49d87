// glint_echo.cpp - print glintd's poses as they arrive (C++11), with the handle owned by a
// unique_ptr so it is closed on every path.
//
//   glint_echo_cpp DOMAIN [STREAM [COUNT]]
//
// Same arguments and output as glint_echo.c, plus the daemon's status once a second on stderr.
#include <glint.h>

#include <chrono>
#include <cinttypes>
#include <cstdio>
#include <memory>
#include <string>

namespace {

struct PoseCloser {
    void operator()(glint_pose_subscriber *s) const { glint_pose_subscriber_close(s); }
};
struct StatusCloser {
    void operator()(glint_status_subscriber *s) const { glint_status_subscriber_close(s); }
};

}  // namespace

int main(int argc, char **argv) {
    if (argc < 2) {
        std::fprintf(stderr, "usage: %s DOMAIN [STREAM [COUNT]]\n", argv[0]);
        return 2;
    }
    const std::string stream = argc > 2 ? argv[2] : "odom";
    const unsigned long count = argc > 3 ? std::stoul(argv[3]) : 0;

    glint_pose_subscriber *raw = nullptr;
    const int opened = glint_pose_subscriber_open(argv[1], stream.c_str(), &raw);
    std::unique_ptr<glint_pose_subscriber, PoseCloser> sub(raw);
    if (opened == GLINT_ERR_INVALID_ARGUMENT) {
        std::fprintf(stderr, "%s\n", glint_pose_subscriber_last_error(sub.get()));
        return 2;
    }
    glint_status_subscriber *raw_status = nullptr;
    glint_status_subscriber_open(argv[1], &raw_status);
    std::unique_ptr<glint_status_subscriber, StatusCloser> status(raw_status);

    auto next_status = std::chrono::steady_clock::now();
    for (unsigned long received = 0; count == 0 || received < count;) {
        glint_pose_v1 p;
        const int rc = glint_pose_subscriber_wait(sub.get(), 1000, &p);
        if (rc == GLINT_OK) {
            std::printf("%" PRIu64 " %" PRIu64 " %.17g %.17g %.17g %.17g %.17g %.17g %.17g 0x%02x\n",
                        p.sequence, p.timestamp_ns, p.position[0], p.position[1], p.position[2],
                        p.orientation[0], p.orientation[1], p.orientation[2], p.orientation[3],
                        static_cast<unsigned>(p.status));
            std::fflush(stdout);
            ++received;
        } else if (rc < 0) {
            std::fprintf(stderr, "%s: %s\n", glint_code_name(rc),
                         glint_pose_subscriber_last_error(sub.get()));
        }
        glint_status_v1 s;
        if (std::chrono::steady_clock::now() >= next_status &&
            glint_status_subscriber_take_latest(status.get(), &s) == GLINT_OK) {
            std::fprintf(stderr, "status: %" PRIu64 " sweeps, p99 latency %.1f ms\n",
                         s.sweeps_processed, static_cast<double>(s.latency_p99_ms));
            next_status += std::chrono::seconds(1);
        }
    }
    return 0;
}
