// Vertex reduction throughput (voxels/s) per method on the CT bunny (when ../shared/data is
// present) and on a synthetic 256³ volume; memory beyond the volume as a counter.
// Machine-readable: run with --benchmark_format=json.
#include <benchmark/benchmark.h>

#include <cstdlib>
#include <filesystem>
#include <map>

#include "adaptiso/reduce.hpp"
#include "adaptiso/synthetic.hpp"
#include "adaptiso/volume_io.hpp"

using namespace adaptiso;

namespace {

std::map<std::string, Volume>& volumes() {
  static std::map<std::string, Volume> v;
  return v;
}

std::size_t octree_bytes(const OctreeMerges& o) {
  std::size_t b = 0;
  for (const auto& m : o.merged) b += m.size();
  return b;
}

void run(benchmark::State& st, const std::string& name, ReduceOptions o) {
  const Volume& v = volumes().at(name);
  ReduceResult r;
  for (auto _ : st) {
    r = reduce(v, o);
    benchmark::DoNotOptimize(r.kept.data());
  }
  st.SetItemsProcessed(st.iterations() * v.voxel_count());
  st.counters["kept"] = static_cast<double>(r.kept.size());
  st.counters["ratio"] = static_cast<double>(r.kept.size()) / static_cast<double>(v.voxel_count());
  st.counters["extra_bytes"] = static_cast<double>(octree_bytes(r.octree) + r.kept.size() * sizeof(std::int64_t));
  st.counters["extra_bytes_per_voxel"] = st.counters["extra_bytes"] / static_cast<double>(v.voxel_count());
}

}  // namespace

int main(int argc, char** argv) {
  volumes()["synthetic_torus_256"] = make_synthetic("torus", 256, ScalarType::f32);
  std::string data = std::getenv("ADAPTISO_DATA") ? std::getenv("ADAPTISO_DATA") : ADAPTISO_SOURCE_DIR "/../shared/data";
  if (std::filesystem::exists(data + "/ct_bunny_stanford.nhdr"))
    volumes()["ct_bunny_stanford"] = read_volume(data + "/ct_bunny_stanford.nhdr");
  else
    std::fprintf(stderr, "note: %s not found; benchmarking the synthetic volume only\n", data.c_str());
  for (const auto& [name, vol] : volumes()) {
    ReduceOptions rec;
    rec.max_error = 0.02;
    rec.relative = true;
    benchmark::RegisterBenchmark((name + "/reconstruction_e0.02").c_str(), run, name, rec)->Unit(benchmark::kMillisecond)->UseRealTime();
    ReduceOptions cen;
    cen.method = ReduceMethod::structural;
    cen.threshold = 0.1;
    cen.relative = true;
    benchmark::RegisterBenchmark((name + "/structural_central").c_str(), run, name, cen)->Unit(benchmark::kMillisecond)->UseRealTime();
    ReduceOptions can = cen;
    can.gradient = GradientOperator::canny;
    benchmark::RegisterBenchmark((name + "/structural_canny_s1").c_str(), run, name, can)
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime()
        ->Iterations(1);
  }
  benchmark::Initialize(&argc, argv);
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
}
