// pingpong.cpp: round trips between two C++ processes, for hetcomm-bench's `cpp-udp-ack` row
// (the same measurement as its Rust `hetcomm-udp-ack` row: system A sends a raw payload to
// system B's module M, B sends it back, A times each round trip).
//
//   pingpong echo FLEET                                   system B: echo until stdin closes
//   pingpong ping FLEET --size N --warmup W --iters I     system A: prints "rtt_ns", then
//                                                         one round trip (ns) per line
#include <hetcomm.hpp>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <iostream>
#include <string>
#include <thread>
#include <unistd.h>
#include <vector>

namespace {
constexpr std::uint32_t kData = 1;

int echo(const std::string& fleet) {
    auto comm = hetcomm::Comm::open(fleet, "B");
    auto m = comm.module("M");
    std::atomic<bool> closed{false};
    // The parent closes our stdin to stop us.
    std::thread([&] {
        char c;
        while (read(0, &c, 1) > 0) {
        }
        closed = true;
    }).detach();
    std::cout << "ready" << std::endl;
    std::vector<std::uint8_t> buf(1 << 20);
    while (!closed) {
        auto n = m.recv_into(buf.data(), buf.size(), nullptr, std::chrono::milliseconds(50));
        if (n) m.send_raw("A", "M", kData, hetcomm::Bytes(buf.data(), *n));
    }
    return 0;
}

int ping(const std::string& fleet, std::size_t size, long warmup, long iters) {
    auto comm = hetcomm::Comm::open(fleet, "A");
    auto m = comm.module("M");
    std::vector<std::uint8_t> msg(size, 7), buf(size + 64);
    auto payload = hetcomm::Bytes(msg.data(), msg.size());
    // Probe until the echo comes back (the peer may still be starting).
    auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(20);
    for (;;) {
        m.send_raw("B", "M", kData, payload);
        if (m.recv_into(buf.data(), buf.size(), nullptr, std::chrono::milliseconds(200))) break;
        if (std::chrono::steady_clock::now() > deadline) {
            std::cerr << "pingpong: no echo within 20 s\n";
            return 1;
        }
    }
    while (m.recv_into(buf.data(), buf.size(), nullptr, std::chrono::milliseconds(0))) {
    }
    std::vector<long long> rtts;
    rtts.reserve(static_cast<std::size_t>(iters));
    long lost = 0;
    for (long i = 0; i < warmup + iters; i++) {
        auto t = std::chrono::steady_clock::now();
        m.send_raw("B", "M", kData, payload);
        if (m.recv_into(buf.data(), buf.size(), nullptr, std::chrono::seconds(1))) {
            auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - t).count();
            if (i >= warmup) rtts.push_back(ns);
        } else if (++lost > 10) {
            std::cerr << "pingpong: more than 10 round trips lost\n";
            return 1;
        }
    }
    std::printf("rtt_ns\n");
    for (auto ns : rtts) std::printf("%lld\n", ns);
    std::fflush(stdout);
    return 0;
}
}  // namespace

int main(int argc, char** argv) {
    if (argc < 3) {
        std::cerr << "usage: pingpong echo FLEET | pingpong ping FLEET --size N --warmup W --iters I\n";
        return 2;
    }
    std::string role = argv[1], fleet = argv[2];
    std::size_t size = 64;
    long warmup = 2000, iters = 20000;
    for (int i = 3; i + 1 < argc; i += 2) {
        std::string a = argv[i];
        if (a == "--size") size = std::stoul(argv[i + 1]);
        else if (a == "--warmup") warmup = std::stol(argv[i + 1]);
        else if (a == "--iters") iters = std::stol(argv[i + 1]);
    }
    try {
        if (role == "echo") return echo(fleet);
        if (role == "ping") return ping(fleet, size, warmup, iters);
        std::cerr << "pingpong: unknown role " << role << "\n";
        return 2;
    } catch (const hetcomm::Error& e) {
        std::cerr << "pingpong: " << e.what() << "\n";
        return 1;
    }
}
