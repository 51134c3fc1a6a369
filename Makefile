# Top-level entry points. `make run`: install dependencies, build (release), render the demo.
# `make test`: install dependencies, build with ASan+UBSan, run the whole test suite; then the same
# for the portable build (no x86-64-v3: the scalar fallbacks of the vector kernels); then the
# memory-limit checks under `ulimit -v` on the release build (sanitizers cannot run under it);
# then each libFuzzer target of tests/fuzz for a fixed number of inputs from a fixed seed and an
# empty corpus, so that every machine fuzzes about the same inputs (clang, ASan+UBSan; at most
# FUZZ_TEST_SECONDS each). `make fuzz` fuzzes for FUZZ_SECONDS from a new seed; `make fuzz-long`:
# the longer fuzzing run for release checks (tests/fuzz/README.md).
JOBS ?= $(shell nproc 2>/dev/null || echo 2)
RELEASE_DIR ?= build/release
TEST_DIR ?= build/test
GENERIC_TEST_DIR ?= build/test-generic
FUZZ_DIR ?= build/fuzz
FUZZ_SECONDS ?= 20
FUZZ_TEST_SECONDS ?= 240
# `make test` fuzzes from a fixed seed so that it is repeatable; `make fuzz` and `make fuzz-long`
# draw a new seed each run (tests/fuzz/README.md).
FUZZ_SEED ?= 1
FUZZ_LONG_SECONDS ?= 900

.PHONY: run test deps build build-test build-test-generic build-fuzz fuzz fuzz-long bench clean

deps:
	@bash scripts/install-deps.sh

build: deps
	cmake -S . -B $(RELEASE_DIR) -DCMAKE_BUILD_TYPE=Release -DNACRE_BUILD_TESTS=OFF
	cmake --build $(RELEASE_DIR) -j $(JOBS)

run: build
	./$(RELEASE_DIR)/nacre render -o nacre.png --stats
	@echo "wrote nacre.png"

build-test: deps
	cmake -S . -B $(TEST_DIR) -DCMAKE_BUILD_TYPE=RelWithDebInfo -DNACRE_SANITIZE=ON -DNACRE_WERROR=ON
	cmake --build $(TEST_DIR) -j $(JOBS)

build-test-generic: deps
	cmake -S . -B $(GENERIC_TEST_DIR) -DCMAKE_BUILD_TYPE=RelWithDebInfo -DNACRE_SANITIZE=ON -DNACRE_WERROR=ON \
		-DNACRE_NATIVE_V3=OFF
	cmake --build $(GENERIC_TEST_DIR) -j $(JOBS)

# Only the fuzz targets, not the CLI: the library with coverage instrumentation and the sanitizers.
build-fuzz: deps
	cmake -S . -B $(FUZZ_DIR) -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ \
		-DCMAKE_BUILD_TYPE=RelWithDebInfo -DNACRE_SANITIZE=ON -DNACRE_FUZZ=ON -DNACRE_BUILD_TESTS=OFF
	cmake --build $(FUZZ_DIR) -j $(JOBS) --target nacre_fuzz

test: build build-test build-test-generic build-fuzz
	cd $(TEST_DIR) && ctest --output-on-failure -j $(JOBS)
	cd $(GENERIC_TEST_DIR) && ctest --output-on-failure -j $(JOBS)
	bash tests/limits.sh $(RELEASE_DIR)/nacre
	rm -rf $(FUZZ_DIR)/fuzz-test
	NACRE_FUZZ_FIXED=1 NACRE_FUZZ_WORK=$(FUZZ_DIR)/fuzz-test NACRE_FUZZ_FLAGS="-seed=$(FUZZ_SEED) $(NACRE_FUZZ_FLAGS)" \
		bash tests/fuzz/run.sh $(FUZZ_DIR) $(FUZZ_TEST_SECONDS)

fuzz: build-fuzz
	bash tests/fuzz/run.sh $(FUZZ_DIR) $(FUZZ_SECONDS)

fuzz-long: build-fuzz
	bash tests/fuzz/run.sh $(FUZZ_DIR) $(FUZZ_LONG_SECONDS)

bench: build
	./$(RELEASE_DIR)/nacre bench raster

clean:
	rm -rf build
