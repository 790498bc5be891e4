# SPDX-License-Identifier: GPL-2.0
# hapticctrl: build the kernel module against the cached test kernel.
#   make            build build/base/module/hapticctrl.ko (builds the test kernel first if needed)
#   make KDIR=...   build against another Rust-enabled kernel build tree
#   make DEBUG=1    build against the debug (lockdep, atomic-sleep) kernel variant
#   make KASAN=1    build against the KASAN kernel variant (debug + generic KASAN; not in CI)
#   make rustfmt    format the module's Rust sources; make rustfmtcheck to check
#   make clean
VARIANT = $(if $(KASAN),kasan,$(if $(DEBUG),debug,base))
KDIR ?= $(shell $(CURDIR)/scripts/build-kernel.sh $(if $(KASAN),--kasan,$(if $(DEBUG),--debug)) 2>/dev/null)
LLVM ?= -22
RUSTC ?= /usr/bin/rustc
# Build output outside the source tree, one directory per kernel variant.
MO ?= $(CURDIR)/build/$(VARIANT)
KO = $(MO)/module/hapticctrl.ko
KMAKE = $(MAKE) -C $(KDIR) M=$(CURDIR) MO=$(MO) LLVM=$(LLVM) RUSTC=$(RUSTC)

all: module

module:
	@test -n "$(KDIR)" || { echo "no kernel tree: run scripts/build-kernel.sh" >&2; exit 1; }
	@mkdir -p $(MO)
	$(KMAKE) modules
	@$(CURDIR)/scripts/check-ko-symbols.sh $(KO)
	@echo "built $(KO)"

clean:
	@test -z "$(KDIR)" || $(KMAKE) clean

RUSTFMT ?= rustfmt
rustfmt:
	$(RUSTFMT) --edition 2021 --config-path $(CURDIR)/module/.rustfmt.toml module/hapticctrl.rs
rustfmtcheck:
	$(RUSTFMT) --check --edition 2021 --config-path $(CURDIR)/module/.rustfmt.toml module/hapticctrl.rs

.PHONY: all module clean rustfmt rustfmtcheck
