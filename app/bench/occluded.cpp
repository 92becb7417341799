// Native Embree 3 casting given segments for occlusion (shadow rays): the native columns of the
// shadow-ray table in BENCHMARKS.md.  gridrt.app.bench.occluded compiles this file (g++ -O3
// -march=native, Debian's libembree-dev) and writes the folder it reads.
//
//   embree_occluded <dir> <threads> <reps> <warmup> [--modes 1,p16,1M] [--robust] [--verdicts]
//
// <dir> holds little-endian C-order .npy files:
//   mesh_<m>.npy                 (F,3,3) float32: the corners of each triangle, m = 0 .. the largest
//                                in batch_mesh.npy
//   batch_mesh.npy               (B,) int32: the mesh each batch of segments is cast against
//   batch_<b>_origins.npy        (N_b,3) float32 \  segment b's rays o + t d, t in [0, 1]: blocked when
//   batch_<b>_directions.npy     (N_b,3) float32 /  a triangle crosses it (rtcOccluded, tnear 0, tfar 1)
//
// A round casts every batch.  Each batch is cut into groups of 64 consecutive segments (the order
// the caller gave: for shadow rays, tile after tile of the image), and <threads> workers, each
// pinned to one of the CPUs the process may use, take 8 groups at a time from one counter that
// runs over every batch's groups.  Modes, each on the same groups:
//   1    rtcOccluded1 per segment
//   p16  rtcOccluded16 on 16 consecutive segments of a group (the last packet of a batch masked)
//   1M   rtcOccluded1M on a group's stream of up to 64 segments
// Per mode: <warmup> untimed rounds, then <reps> timed ones; one line "RESULT {json}" with the
// median, least and greatest ms of a round.  --verdicts writes the last round's flags (uint8, 1 =
// blocked; the batches' segments one after another) to <dir>/verdicts_<mode>.npy.
// Scenes: one per mesh, Embree's default build quality (MEDIUM), built before any timing; the
// ROBUST scene flag with --robust.  The device gets threads=<threads> (its builders' pool).
#include <embree3/rtcore.h>
#include <pmmintrin.h>
#include <pthread.h>
#include <sched.h>
#include <xmmintrin.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

namespace {

[[noreturn]] void fail(const std::string& why) {
  std::fprintf(stderr, "embree_occluded: %s\n", why.c_str());
  std::exit(2);
}

void on_error(void*, RTCError code, const char* what) {
  fail("Embree error " + std::to_string(static_cast<int>(code)) + ": " + (what ? what : "(no message)"));
}

double seconds() {
  using clock = std::chrono::steady_clock;
  return std::chrono::duration<double>(clock::now().time_since_epoch()).count();
}

// ------------------------------------------------------------------------------- .npy in and out

struct Npy {
  std::vector<size_t> shape;
  std::vector<float> f32;  // float32 data, 16 floats of padding (Embree may read past the last vertex)
  std::vector<int32_t> i32;
};

// Reads `path`, whose dtype must be `descr` ("<f4" or "<i4"), C order.
Npy read_npy(const std::string& path, const std::string& descr) {
  FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) fail("cannot open " + path);
  unsigned char head[10];
  if (std::fread(head, 1, 10, f) != 10 || std::memcmp(head, "\x93NUMPY", 6) != 0) fail(path + " is not a .npy file");
  size_t len = head[8] | (head[9] << 8);
  if (head[6] >= 2) {  // versions 2 and 3: a 4-byte header length
    unsigned char more[2];
    if (std::fread(more, 1, 2, f) != 2) fail(path + ": truncated header");
    len |= (static_cast<size_t>(more[0]) << 16) | (static_cast<size_t>(more[1]) << 24);
  }
  std::string dict(len, ' ');
  if (std::fread(&dict[0], 1, len, f) != len) fail(path + ": truncated header");
  if (dict.find("'descr': '" + descr + "'") == std::string::npos) fail(path + ": its dtype must be " + descr);
  if (dict.find("'fortran_order': False") == std::string::npos) fail(path + ": must be in C order");
  size_t at = dict.find("'shape': (");
  if (at == std::string::npos) fail(path + ": no shape in its header");
  Npy a;
  for (const char* s = dict.c_str() + at + 10; *s && *s != ')';) {
    if (*s == ',' || *s == ' ') { ++s; continue; }
    char* end = nullptr;
    a.shape.push_back(std::strtoull(s, &end, 10));
    if (end == s) fail(path + ": unreadable shape");
    s = end;
  }
  size_t n = 1;
  for (size_t d : a.shape) n *= d;
  size_t got = 0;
  if (descr == "<f4") {
    a.f32.assign(n + 16, 0.f);
    got = std::fread(a.f32.data(), 4, n, f);
  } else {
    a.i32.assign(n, 0);
    got = std::fread(a.i32.data(), 4, n, f);
  }
  std::fclose(f);
  if (got != n) fail(path + ": truncated data");
  return a;
}

void write_flags(const std::string& path, const std::vector<uint8_t>& flags) {
  std::string dict = "{'descr': '|u1', 'fortran_order': False, 'shape': (" + std::to_string(flags.size()) + ",), }";
  while ((10 + dict.size() + 1) % 64) dict.push_back(' ');
  dict.push_back('\n');
  FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) fail("cannot write " + path);
  const unsigned char head[10] = {0x93, 'N', 'U', 'M', 'P', 'Y', 1, 0, static_cast<unsigned char>(dict.size() & 255),
                                  static_cast<unsigned char>(dict.size() >> 8)};
  std::fwrite(head, 1, 10, f);
  std::fwrite(dict.data(), 1, dict.size(), f);
  std::fwrite(flags.data(), 1, flags.size(), f);
  std::fclose(f);
}

// ------------------------------------------------------------------------------- the work

struct Batch {
  RTCScene scene;
  Npy o, d;
  size_t n;      // segments
  size_t first;  // its first segment's place among all batches' segments
};

struct Group {  // up to 64 consecutive segments of one batch
  const Batch* batch;
  size_t start, count;
};

enum class Mode { single, packet16, stream };

Mode parse_mode(const std::string& s) {
  if (s == "1") return Mode::single;
  if (s == "p16") return Mode::packet16;
  if (s == "1M") return Mode::stream;
  fail("unknown mode " + s + " (1, p16, 1M)");
}

void set_ray(RTCRay& r, const Batch& b, size_t i) {
  r.org_x = b.o.f32[3 * i]; r.org_y = b.o.f32[3 * i + 1]; r.org_z = b.o.f32[3 * i + 2];
  r.dir_x = b.d.f32[3 * i]; r.dir_y = b.d.f32[3 * i + 1]; r.dir_z = b.d.f32[3 * i + 2];
  r.tnear = 0.f; r.tfar = 1.f; r.time = 0.f;
  r.mask = 0xFFFFFFFFu; r.id = static_cast<unsigned>(i); r.flags = 0;
}

// Casts one group; flags[first + i] = 1 where segment i is blocked (Embree sets its tfar to -inf).
void cast_group(const Group& g, Mode mode, uint8_t* flags) {
  const Batch& b = *g.batch;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
  uint8_t* out = flags + b.first;
  if (mode == Mode::single) {
    for (size_t i = g.start; i < g.start + g.count; ++i) {
      RTCRay r;
      set_ray(r, b, i);
      rtcOccluded1(b.scene, &ctx, &r);
      out[i] = r.tfar < 0.f;
    }
  } else if (mode == Mode::packet16) {
    for (size_t i0 = g.start; i0 < g.start + g.count; i0 += 16) {
      alignas(64) RTCRay16 r;
      alignas(64) int valid[16];
      size_t m = std::min<size_t>(16, g.start + g.count - i0);
      for (size_t j = 0; j < 16; ++j) {
        size_t i = i0 + std::min(j, m - 1);  // (masked lanes repeat the last segment)
        valid[j] = j < m ? -1 : 0;
        r.org_x[j] = b.o.f32[3 * i]; r.org_y[j] = b.o.f32[3 * i + 1]; r.org_z[j] = b.o.f32[3 * i + 2];
        r.dir_x[j] = b.d.f32[3 * i]; r.dir_y[j] = b.d.f32[3 * i + 1]; r.dir_z[j] = b.d.f32[3 * i + 2];
        r.tnear[j] = 0.f; r.tfar[j] = 1.f; r.time[j] = 0.f;
        r.mask[j] = 0xFFFFFFFFu; r.id[j] = static_cast<unsigned>(j); r.flags[j] = 0;
      }
      rtcOccluded16(valid, b.scene, &ctx, &r);
      for (size_t j = 0; j < m; ++j) out[i0 + j] = r.tfar[j] < 0.f;
    }
  } else {
    alignas(64) RTCRay rays[64];
    for (size_t j = 0; j < g.count; ++j) set_ray(rays[j], b, g.start + j);
    rtcOccluded1M(b.scene, &ctx, rays, static_cast<unsigned>(g.count), sizeof(RTCRay));
    for (size_t j = 0; j < g.count; ++j) out[g.start + j] = rays[j].tfar < 0.f;
  }
}

std::vector<int> allowed_cpus() {
  cpu_set_t set;
  CPU_ZERO(&set);
  sched_getaffinity(0, sizeof set, &set);
  std::vector<int> cpus;
  for (int c = 0; c < CPU_SETSIZE; ++c)
    if (CPU_ISSET(c, &set)) cpus.push_back(c);
  return cpus;
}

void flush_denormals() {  // what Embree asks of every thread that traces
  _MM_SET_FLUSH_ZERO_MODE(_MM_FLUSH_ZERO_ON);
  _MM_SET_DENORMALS_ZERO_MODE(_MM_DENORMALS_ZERO_ON);
}

// One round over every group with `threads` workers; its wall time in seconds.
double round_of(const std::vector<Group>& groups, Mode mode, int threads, const std::vector<int>& cpus,
                uint8_t* flags) {
  std::atomic<size_t> next{0};
  auto work = [&](int w) {
    if (threads > 1) {
      cpu_set_t one;
      CPU_ZERO(&one);
      CPU_SET(cpus[w % cpus.size()], &one);
      pthread_setaffinity_np(pthread_self(), sizeof one, &one);
      flush_denormals();
    }
    for (;;) {
      size_t g0 = next.fetch_add(8);
      if (g0 >= groups.size()) return;
      for (size_t g = g0; g < std::min(groups.size(), g0 + 8); ++g) cast_group(groups[g], mode, flags);
    }
  };
  double t0 = seconds();
  if (threads == 1) {
    work(0);
  } else {
    std::vector<std::thread> pool;
    for (int w = 0; w < threads; ++w) pool.emplace_back(work, w);
    for (auto& t : pool) t.join();
  }
  return seconds() - t0;
}

std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> out;
  size_t a = 0;
  while (a <= s.size()) {
    size_t b = s.find(',', a);
    if (b == std::string::npos) b = s.size();
    if (b > a) out.push_back(s.substr(a, b - a));
    a = b + 1;
  }
  return out;
}

int whole(const char* s, const char* what, int least) {
  char* end = nullptr;
  long v = std::strtol(s, &end, 10);
  if (end == s || *end || v < least) fail(std::string(what) + " must be a whole number >= " + std::to_string(least));
  return static_cast<int>(v);
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 5)
    fail("usage: embree_occluded <dir> <threads> <reps> <warmup> [--modes 1,p16,1M] [--robust] [--verdicts]");
  const std::string dir = argv[1];
  const int threads = whole(argv[2], "threads", 1), reps = whole(argv[3], "reps", 1);
  const int warmup = whole(argv[4], "warmup", 0);
  std::vector<std::string> modes = {"1", "p16", "1M"};
  bool robust = false, verdicts = false;
  for (int i = 5; i < argc; ++i) {
    std::string a = argv[i];
    if (a == "--modes" && i + 1 < argc) modes = split(argv[++i]);
    else if (a == "--robust") robust = true;
    else if (a == "--verdicts") verdicts = true;
    else fail("unknown argument " + a);
  }
  for (const auto& m : modes) parse_mode(m);
  flush_denormals();
  std::string config = "threads=" + std::to_string(threads);
  RTCDevice dev = rtcNewDevice(config.c_str());
  if (!dev) fail("rtcNewDevice failed");
  rtcSetDeviceErrorFunction(dev, on_error, nullptr);

  Npy which = read_npy(dir + "/batch_mesh.npy", "<i4");
  if (which.shape.size() != 1) fail("batch_mesh.npy must be (B,)");
  int32_t last = -1;
  for (int32_t m : which.i32) {
    if (m < 0) fail("batch_mesh.npy: a mesh number below 0");
    last = std::max(last, m);
  }
  std::vector<Npy> meshes;
  size_t most = 0;
  for (int32_t m = 0; m <= last; ++m) {
    meshes.push_back(read_npy(dir + "/mesh_" + std::to_string(m) + ".npy", "<f4"));
    const Npy& t = meshes.back();
    if (t.shape.size() != 3 || t.shape[1] != 3 || t.shape[2] != 3) fail("mesh_<m>.npy must be (F,3,3)");
    most = std::max(most, t.shape[0]);
  }
  // one index buffer for every mesh (triangle f: vertices 3f, 3f + 1, 3f + 2), which Embree shares:
  // sized for the largest mesh before any scene holds it
  std::vector<uint32_t> index(3 * most);
  for (size_t i = 0; i < index.size(); ++i) index[i] = static_cast<uint32_t>(i);
  std::vector<RTCScene> scenes;
  for (const Npy& t : meshes) {
    size_t F = t.shape[0];
    RTCScene sc = rtcNewScene(dev);
    rtcSetSceneFlags(sc, robust ? RTC_SCENE_FLAG_ROBUST : RTC_SCENE_FLAG_NONE);
    RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, t.f32.data(), 0, 12, 3 * F);
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, index.data(), 0, 12, F);
    rtcCommitGeometry(g);
    rtcAttachGeometry(sc, g);
    rtcReleaseGeometry(g);
    rtcCommitScene(sc);
    scenes.push_back(sc);
  }
  std::vector<Batch> batches(which.i32.size());
  size_t total = 0;
  for (size_t b = 0; b < batches.size(); ++b) {
    Batch& x = batches[b];
    std::string stem = dir + "/batch_" + std::to_string(b);
    x.o = read_npy(stem + "_origins.npy", "<f4");
    x.d = read_npy(stem + "_directions.npy", "<f4");
    if (x.o.shape.size() != 2 || x.o.shape[1] != 3 || x.d.shape != x.o.shape)
      fail(stem + ": origins and directions must both be (N,3)");
    x.scene = scenes[which.i32[b]];
    x.n = x.o.shape[0];
    x.first = total;
    total += x.n;
  }
  std::vector<Group> groups;
  for (const Batch& b : batches)
    for (size_t s = 0; s < b.n; s += 64) groups.push_back({&b, s, std::min<size_t>(64, b.n - s)});

  const std::vector<int> cpus = allowed_cpus();
  std::vector<uint8_t> flags(total);
  for (const auto& name : modes) {
    Mode mode = parse_mode(name);
    for (int r = 0; r < warmup; ++r) round_of(groups, mode, threads, cpus, flags.data());
    std::vector<double> ms;
    for (int r = 0; r < reps; ++r) ms.push_back(1e3 * round_of(groups, mode, threads, cpus, flags.data()));
    std::sort(ms.begin(), ms.end());
    double med = ms.size() % 2 ? ms[ms.size() / 2] : 0.5 * (ms[ms.size() / 2 - 1] + ms[ms.size() / 2]);
    size_t blocked = 0;
    for (uint8_t v : flags) blocked += v;
    std::printf("RESULT {\"mode\": \"%s\", \"robust\": %s, \"threads\": %d, \"segments\": %zu, \"batches\": %zu, "
                "\"blocked\": %zu, \"ms\": %.4f, \"ms_min\": %.4f, \"ms_max\": %.4f}\n",
                name.c_str(), robust ? "true" : "false", threads, total, batches.size(), blocked, med, ms.front(),
                ms.back());
    std::fflush(stdout);
    if (verdicts) write_flags(dir + "/verdicts_" + name + ".npy", flags);
  }
  for (RTCScene sc : scenes) rtcReleaseScene(sc);
  rtcReleaseDevice(dev);
  return 0;
}
