# The headline accuracy run under examples/PROTOCOL.md, included by the Makefile:
#
#   make -C examples accuracy -j2 [ACC_TIER=winkler] [DEVICE=cuda]   # both regimes, from the committed configs
#   make -C examples tune -j2 [ACC_TIER=winkler]                       # the tuning searches behind those configs
#
# Six imagers: the paper's pair (`less`, `global`), ours (`less-taxel`) and its global partner
# (`global-taxel`), 3 seeds each, beside the classical force-map imager and the average baseline. Two
# regimes, the same imagers and settings in both:
#   ours   trained on the randomised single-inclusion family of scenes/quick.toml, validated on inserts of
#          that family held apart, tested on catalogue phantoms no model saw: single (30 inserts x 2
#          orientations), multiple (10 x 2), large (6 x 3 sizes; local models grow their grid), hand-held-like
#          primitives with pose noise. Tables: results/accuracy$(ACC_SUFFIX)/
#   paper  the authors' split: the catalogue's single inserts at all 8 orientations, split by scan file (an
#          insert may sit in training and test at another orientation), tested on the held-out scans, on
#          multiple and on large, and scored on its own training scans. Tables: results/accuracy-paper$(ACC_SUFFIX)/
# Every learned imager reads its settings from tuning/<tier>/<model>.toml: the best of the same six trials
# (tuning/space.toml) on the validation scans of our regime (`make tune`, examples/tune.py; logs in
# results/tuning-<tier>/). Test sets are read by the `accuracy` target only.

ACC_TIER   ?= green
# the full protocol (green) writes results/accuracy/ and results/accuracy-paper/; another tier's run of it
# results/accuracy-protocol-<tier>/ and results/accuracy-paper-protocol-<tier>/
ACC_SUFFIX := $(if $(filter green,$(ACC_TIER)),,-protocol-$(ACC_TIER))
A          := work/accuracy-$(ACC_TIER)
P          := $(A)/paper
AR         := results/accuracy$(ACC_SUFFIX)
PR         := results/accuracy-paper$(ACC_SUFFIX)
CFG        := tuning/$(ACC_TIER)
TUNE_LOG   := results/tuning-$(ACC_TIER)
# the first run's configs (the best of the frozen trials 0-3): the diagnosis and the scaling study of the
# paper's pair were made with them and read them still; their self-supervision is the current configs' too
FCFG       := $(CFG)/frozen
PYTHON     ?= python3
ACC_MODELS := less global less-taxel global-taxel
ACC_COUNT  ?= 240
ACC_EVERY_handheld := 10
ACC_SIM_train    := --set phantoms.random.count=$(ACC_COUNT)
ACC_SIM_single   := --set phantoms.set=single --set 'phantoms.orientations=[0,4]'
ACC_SIM_paper    := --set phantoms.set=single --set 'phantoms.orientations=[0,1,2,3,4,5,6,7]'
ACC_SIM_multiple := --set phantoms.set=multiple --set 'phantoms.orientations=[0,4]'
ACC_SIM_large    := --set phantoms.set=large --set 'phantoms.orientations=[0]' --set motion.n_traj=120 \
                    --set 'labels.spacing_mm=[1.8,1.9096,1.9096]'
ACC_SIM_handheld := $(ACC_SIM_single) --set motion.kind=primitive --set motion.n_traj=20 \
                    --set 'motion.primitives=["jab","back_and_forth","left_and_right"]' --set effects.pose.mode=handheld
OURS_SETS  := single multiple large handheld
PAPER_SETS := test multiple large train
# a config entry in a pattern rule's recipe: $(call tune_arg,MODEL,KEY)
tune_arg    = $$($(PYTHON) tune.py args $(CFG)/$(1).toml $(2))

# ---------------------------------------------------------------- data
ACC_SIM_JOBS_train := $(NPROC)
$(A)/raw_%.npz: scenes/quick.toml
	@mkdir -p $(@D)
	$(LESS) simulate $< -o $@ --jobs $(or $(ACC_SIM_JOBS_$*),$(THREADS)) --set contact.tier=$(ACC_TIER) \
	  $(ACC_SIM_$*) > /dev/null
$(A)/%.npz: $(A)/raw_%.npz
	$(LESS) subsample $< --every $(or $(ACC_EVERY_$*),50) -o $@
# ours: 102 inserts for training, 36 for validation (by insert); the other 102 are a reserve the protocol
# keeps for the scaling study (more training scans), never for a choice
$(A)/split/train.npz $(A)/split/val.npz $(A)/split/reserve.npz &: $(A)/train.npz
	$(LESS) split $< --by insert --test 0.425 --val 0.15 --seed 0 -o $(A)/split/ > /dev/null
	mv $(A)/split/test.npz $(A)/split/reserve.npz
# the paper's: by scan file, 70 / 10 / 20 % (its epochs and labelling chosen on val.npz)
$(P)/train.npz $(P)/val.npz $(P)/test.npz &: $(A)/paper.npz
	$(LESS) split $< --by scan --test 0.2 --val 0.1 --seed 0 -o $(P)/ > /dev/null
$(P)/multiple.npz $(P)/large.npz: $(P)/%.npz: $(A)/%.npz
	@mkdir -p $(@D)
	ln -sf ../$*.npz $@

# ---------------------------------------------------------------- tuning (validation data only)
# on half the training inserts (51), scored on the whole validation split: a search the 2-core budget allows
$(A)/search/train.npz: $(A)/split/train.npz
	$(LESS) split $< --by insert --test 0.5 --seed 0 -o $(A)/search/ > /dev/null
# `make tune` runs every search (a trial already in its log is not run again: delete the log for a new
# search); a missing config is made by its search, a committed one is used as it is
TUNE = $(PYTHON) tune.py run --model $* --space tuning/space.toml --train $(A)/search/train.npz \
  --val $(A)/split/val.npz --work $(A)/tune/$* --log $(TUNE_LOG)/$*.jsonl -o $(CFG)/$*.toml --device $(DEVICE) \
  --threads $(THREADS) --less '$(LESS)'
.PHONY: tune $(foreach m,$(ACC_MODELS),tune-$(m))
tune: $(foreach m,$(ACC_MODELS),tune-$(m))
$(foreach m,$(ACC_MODELS),tune-$(m)): tune-%: $(A)/search/train.npz $(A)/split/val.npz
	$(TUNE)
$(CFG)/%.toml: | $(A)/search/train.npz $(A)/split/val.npz
	$(TUNE)

# ---------------------------------------------------------------- training: <regime dir>/{rep,img}_<model>_s<seed>.pt
# $(1) model, $(2) seed, $(3) regime folder, $(4) its training set, $(5) its validation set
define ACC_TRAIN
$(3)/rep_$(1)_s$(2).pt: $(4) $(5) $(CFG)/$(1).toml
	$(LESS) pretrain $(4) --val $(5) -o $$@ --model $(1) --seed $(2) --device $(DEVICE) \
	  $$$$($(PYTHON) tune.py args $(CFG)/$(1).toml pretrain) --format jsonl > $$@.json
$(3)/img_$(1)_s$(2).pt: $(3)/rep_$(1)_s$(2).pt
	$(LESS) image fit $(4) --val $(5) --rep $$< -o $$@ --dim 3 --seed $(2) --device $(DEVICE) \
	  $$$$($(PYTHON) tune.py args $(CFG)/$(1).toml fit) --format jsonl > $$@.json
endef
$(foreach s,$(SEEDS),$(foreach m,$(ACC_MODELS),$(eval $(call ACC_TRAIN,$(m),$(s),$(A),$(A)/split/train.npz,$(A)/split/val.npz))))
$(foreach s,$(SEEDS),$(foreach m,$(ACC_MODELS),$(eval $(call ACC_TRAIN,$(m),$(s),$(P),$(P)/train.npz,$(P)/val.npz))))
$(A)/forcemap.pt: $(A)/split/train.npz
	$(LESS) image fit $< --model forcemap -o $@ --format jsonl > $@.json
$(P)/forcemap.pt: $(P)/train.npz
	$(LESS) image fit $< --model forcemap -o $@ --format jsonl > $@.json

# ---------------------------------------------------------------- predictions: <regime dir>/pred_<imager>_on_<set>.npz
# each learned imager with its own config's turns; local ones grow their particle grid over the large inserts
# the model behind an imager stem: img_<model>[-<variant>]_s<seed> (variants: -full, -init, -maponly, -frozen,
# -endtoend, -long, -endtoend-long, -fast, -fast-endtoend, -fit, -last, -e100, -n<N>-d<D>)
strip_variant = $(patsubst %-e100,%,$(patsubst %-last,%,$(patsubst %-fit,%,$(patsubst %-full,%,$(patsubst %-maponly,%,$(patsubst %-init,%,$(patsubst %-frozen,%,$(patsubst %-fast,%,$(patsubst %-endtoend,%,$(patsubst %-long,%,$(1)))))))))))
model_of = $(firstword $(subst -n, ,$(call strip_variant,$(word 2,$(subst _, ,$(1))))))
define ACC_PREDICT
$(1)/pred_%_on_$(2).npz: $(1)/%.pt $(1)/$(2).npz
	$(LESS) image predict $$< $(1)/$(2).npz -o $$@ --device $(DEVICE) \
	  $$(if $$(findstring img_,$$*),--turns $$(call tune_arg,$$(call model_of,$$*),turns)) \
	  $$(if $$(and $$(filter large,$(2)),$$(filter less less-taxel,$$(call model_of,$$*))),--grow) > /dev/null
endef
$(foreach t,$(OURS_SETS),$(eval $(call ACC_PREDICT,$(A),$(t))))
$(foreach t,$(PAPER_SETS),$(eval $(call ACC_PREDICT,$(P),$(t))))

imagers    = forcemap $(foreach m,$(ACC_MODELS),$(foreach s,$(SEEDS),img_$(m)_s$(s)))
OURS_PREDS  := $(foreach t,$(OURS_SETS),$(foreach i,$(imagers),$(A)/pred_$(i)_on_$(t).npz))
PAPER_PREDS := $(foreach t,$(PAPER_SETS),$(foreach i,$(imagers),$(P)/pred_$(i)_on_$(t).npz))

# ---------------------------------------------------------------- tables
# phony, so that a table is written again whenever asked (the Makefile's .SECONDARY would take a table
# as up to date while predictions of added seeds are missing)
.PHONY: accuracy accuracy-ours accuracy-paper
accuracy: accuracy-ours accuracy-paper
# $(1) table folder, $(2) predictions, $(3) training set of the average baseline
define ACC_TABLE
	@mkdir -p $(1)
	$(LESS) metrics $(2) --baseline-from $(3) --group-by set,model --summary-only --format jsonl > $(1)/accuracy.jsonl
	$(LESS) metrics $(2) --baseline-from $(3) --group-by set,model --summary-only --format markdown \
	  > $(1)/accuracy.md.part && mv $(1)/accuracy.md.part $(1)/accuracy.md
	$(PYTHON) headline.py $(1)/accuracy.jsonl > $(1)/headline.md
endef
accuracy-ours: $(OURS_PREDS)
	$(call ACC_TABLE,$(AR),$^,$(A)/split/train.npz)
accuracy-paper: $(PAPER_PREDS)
	$(call ACC_TABLE,$(PR),$^,$(P)/train.npz)

# ---------------------------------------------------------------- the parts of less-taxel (our regime, 3 seeds)
#   make -C examples ablation -j2 [ACC_TIER=winkler]      -> results/ablation-<tier>/ablation.md
# full: the headline's models; init: the GRU at initialisation (one SSL step of lr 1e-12, so no
# self-supervision); maponly: a GRU of one untrained unit, so the decoder reads the stiffness map alone.
ABL := $(A)/ablation
ABR := results/ablation-$(ACC_TIER)
ABL_init    := --epochs 1 --lr 1e-12
ABL_maponly := --dim 1 --epochs 1 --lr 1e-12
ABL_SETS    := val single multiple
define ABL_TRAIN
$(ABL)/rep_less-taxel-$(1)_s$(2).pt: $(A)/split/train.npz $(A)/split/val.npz $(CFG)/less-taxel.toml
	@mkdir -p $$(@D)
	$(LESS) pretrain $(A)/split/train.npz --val $(A)/split/val.npz -o $$@ --model less-taxel --seed $(2) \
	  --device $(DEVICE) $$$$($(PYTHON) tune.py args $(CFG)/less-taxel.toml pretrain) $(ABL_$(1)) --format jsonl > $$@.json
$(ABL)/img_less-taxel-$(1)_s$(2).pt: $(ABL)/rep_less-taxel-$(1)_s$(2).pt
	$(LESS) image fit $(A)/split/train.npz --val $(A)/split/val.npz --rep $$< -o $$@ --dim 3 --seed $(2) \
	  --device $(DEVICE) $$$$($(PYTHON) tune.py args $(CFG)/less-taxel.toml fit) --format jsonl > $$@.json
endef
$(foreach s,$(SEEDS),$(foreach v,init maponly,$(eval $(call ABL_TRAIN,$(v),$(s)))))
$(ABL)/img_less-taxel-full_s%.pt: $(A)/img_less-taxel_s%.pt
	@mkdir -p $(@D)
	ln -sf ../$(<F) $@
$(ABL)/val.npz $(ABL)/single.npz $(ABL)/multiple.npz: $(ABL)/%.npz: | $(A)/split/val.npz $(A)/single.npz $(A)/multiple.npz
	@mkdir -p $(@D)
	ln -sf $(if $(filter val,$*),../split/val.npz,../$*.npz) $@
$(foreach t,$(ABL_SETS),$(eval $(call ACC_PREDICT,$(ABL),$(t))))
ABL_PREDS := $(foreach t,$(ABL_SETS),$(foreach v,full init maponly,$(foreach s,$(SEEDS),$(ABL)/pred_img_less-taxel-$(v)_s$(s)_on_$(t).npz)))
.PHONY: ablation
ablation: $(ABL_PREDS)
	@mkdir -p $(ABR)
	$(LESS) metrics $^ --summary-only --format jsonl > $(ABR)/ablation.jsonl
	$(PYTHON) headline.py $(ABR)/ablation.jsonl --no-paper > $(ABR)/ablation.md.part && mv $(ABR)/ablation.md.part $(ABR)/ablation.md

# ---------------------------------------------------------------- scaling: the paper's pair against data and width
#   make -C examples scaling -j2 [ACC_TIER=winkler] [DEVICE=cuda SCALE_DIMS="16 64 256 1024"]
# `less` and `global` (each with its config's other settings, seed 0) trained on 51 / 102 / 204 inserts of
# the family (204: the training split and the reserve) at d_z SCALE_DIMS (one model's own: SCALE_DIMS_<model>,
# e.g. SCALE_DIMS_less="16 64" where its widest trainings do not fit the time), scored on the validation
# split; results/scaling-<tier>/scaling.md with each training's seconds (results/scaling-<tier>/times.jsonl).
SC  := $(A)/scaling
SCR := results/scaling-$(ACC_TIER)
SCALE_MODELS ?= less global
SCALE_DIMS   ?= 16 64 256
SCALE_SCANS  := 51 102 204
scale_dims    = $(or $(SCALE_DIMS_$(1)),$(SCALE_DIMS))
$(SC)/train51.npz: $(A)/search/train.npz
	@mkdir -p $(@D)
	ln -sf ../search/train.npz $@
$(SC)/train102.npz: $(A)/split/train.npz
	@mkdir -p $(@D)
	ln -sf ../split/train.npz $@
$(SC)/train204.npz: $(A)/split/train.npz $(A)/split/reserve.npz
	@mkdir -p $(@D)
	$(LESS) concat $^ -o $@
$(SC)/val.npz: | $(A)/split/val.npz
	@mkdir -p $(@D)
	ln -sf ../split/val.npz $@
# one seed-0 training of a study (scaling, density): $(1) folder, $(2) model, $(3) the variant in its stem
# (img_<model>-<variant>_s0), $(4) training set, $(5) validation set, $(6) config folder, $(7) extra
# self-supervision arguments
define STUDY_TRAIN
$(1)/rep_$(2)-$(3)_s0.pt: $(4) $(5) $(6)/$(2).toml
	$(LESS) pretrain $(4) --val $(5) -o $$@ --model $(2) --seed 0 --device $(DEVICE) \
	  $$$$($(PYTHON) tune.py args $(6)/$(2).toml pretrain) $(7) --format jsonl > $$@.json
$(1)/img_$(2)-$(3)_s0.pt: $(1)/rep_$(2)-$(3)_s0.pt
	$(LESS) image fit $(4) --val $(5) --rep $$< -o $$@ --dim 3 --seed 0 --device $(DEVICE) \
	  $$$$($(PYTHON) tune.py args $(6)/$(2).toml fit) --format jsonl > $$@.json
endef
# each training's seconds (self-supervision and imaging fit) behind a study's predictions on val.npz:
# $(1) those predictions, $(2) the JSON lines written
define STUDY_TIMES
	for f in $(subst /pred_,/,$(1:_on_val.npz=.pt)); do \
	  $(PYTHON) -c 'import json,sys; a,b=(json.loads(open(p).read().splitlines()[-1]) for p in sys.argv[2:]); print(json.dumps({"imager": sys.argv[1], "seconds": a["seconds"] + b["seconds"]}))' \
	    $$(basename $$f .pt) $$(echo $$f | sed 's|/img_|/rep_|').json $$f.json || exit 1; done > $(2)
endef
$(foreach m,$(SCALE_MODELS),$(foreach n,$(SCALE_SCANS),$(foreach d,$(call scale_dims,$(m)),$(eval $(call STUDY_TRAIN,$(SC),$(m),n$(n)-d$(d),$(SC)/train$(n).npz,$(SC)/val.npz,$(FCFG),--dim $(d))))))
$(eval $(call ACC_PREDICT,$(SC),val))
SCALE_PREDS := $(foreach m,$(SCALE_MODELS),$(foreach n,$(SCALE_SCANS),$(foreach d,$(call scale_dims,$(m)),$(SC)/pred_img_$(m)-n$(n)-d$(d)_s0_on_val.npz)))
# the study tables are written by their phony targets, as the headline's are (a study given more models
# or variants is tabled again)
.PHONY: scaling
scaling: $(SCALE_PREDS)
	@mkdir -p $(SCR)
	$(LESS) metrics $^ --summary-only --format jsonl > $(SCR)/scaling.jsonl
	$(call STUDY_TIMES,$(SCALE_PREDS),$(SCR)/times.jsonl)
	$(PYTHON) headline.py $(SCR)/scaling.jsonl --no-paper --times $(SCR)/times.jsonl > $(SCR)/scaling.md.part \
	  && mv $(SCR)/scaling.md.part $(SCR)/scaling.md

# ---------------------------------------------------------------- what holds the paper's pair back
#   make -C examples diagnose -j2 [ACC_TIER=winkler]      -> results/diagnose-<tier>/diagnose.md
# each of `less` and `global` with its config, seed 0, on the search scans: the imaging fit with the
# representation frozen (as published) and trained end to end with the imaging loss (--finetune). If the
# end-to-end fit images the validation scans and the frozen one cannot, the architecture can hold the
# inclusion and self-supervision at this budget is what loses it. The end-to-end fit is also run with five
# times the imaging epochs (-endtoend-long): a model that fits its training scans there is held back by the
# budget, one that does not by its capacity or its optimisation.
DIAG_LONG_EPOCHS ?= 100
DG  := $(A)/diagnose
DGR := results/diagnose-$(ACC_TIER)
DIAG_MODELS ?= less global
define DIAG_TRAIN
$(DG)/rep_$(1)_s0.pt: $(A)/search/train.npz $(A)/split/val.npz $(FCFG)/$(1).toml
	@mkdir -p $$(@D)
	$(LESS) pretrain $(A)/search/train.npz --val $(A)/split/val.npz -o $$@ --model $(1) --seed 0 --device $(DEVICE) \
	  $$$$($(PYTHON) tune.py args $(FCFG)/$(1).toml pretrain) --format jsonl > $$@.json
endef
# the imaging fits: $(1) model, $(2) variant (its own fit arguments: DIAG_FIT_<variant>)
DIAG_VARIANTS          := frozen endtoend endtoend-long
DIAG_FIT_frozen        :=
DIAG_FIT_endtoend      := --finetune
DIAG_FIT_endtoend-long := --finetune --epochs $(DIAG_LONG_EPOCHS)
define DIAG_FIT
$(DG)/img_$(1)-$(2)_s0.pt: $(DG)/rep_$(1)_s0.pt
	$(LESS) image fit $(A)/search/train.npz --val $(A)/split/val.npz --rep $$< -o $$@ --dim 3 --seed 0 \
	  --device $(DEVICE) $$$$($(PYTHON) tune.py args $(FCFG)/$(1).toml fit) $(DIAG_FIT_$(2)) --format jsonl > $$@.json
endef
$(foreach m,$(DIAG_MODELS),$(foreach v,$(DIAG_VARIANTS),$(eval $(call DIAG_FIT,$(m),$(v)))))
$(foreach m,$(DIAG_MODELS),$(eval $(call DIAG_TRAIN,$(m))))
# capacity: the paper regime's seed-0 representation, decoded with five times the imaging epochs (100), scored
# on its own training scans and on its validation scans (not the test scans): can the model fit what it was
# trained on?
# $(1) model, $(2) variant (its own fit arguments: DIAG_FIT_<variant>)
DIAG_FIT_long := --epochs $(DIAG_LONG_EPOCHS)
define DIAG_PAPER
$(P)/img_$(1)-$(2)_s0.pt: $(P)/rep_$(1)_s0.pt
	$(LESS) image fit $(P)/train.npz --val $(P)/val.npz --rep $$< -o $$@ --dim 3 --seed 0 --device $(DEVICE) \
	  $$$$($(PYTHON) tune.py args $(FCFG)/$(1).toml fit) $(DIAG_FIT_$(2)) --format jsonl > $$@.json
endef
$(foreach m,$(DIAG_MODELS),$(eval $(call DIAG_PAPER,$(m),long)))
# global's decoder: `make -C examples decoder -j2 [ACC_TIER=winkler]` -> results/diagnose-<tier>/decoder*.
# decoder_oracle.py fits the global decoder to codes that hold the answer (its ceiling at an imaging setting);
# `global`'s own states are decoded with the search's other imaging level (trial 0's: lr 1e-2, power 0.5,
# width 16, -fast), frozen and end to end, on the search scans and in the paper's regime (its val, not test)
DIAG_FAST := --lr 1e-2 --set loss.alpha_power=0.5 --set image.width=16
DIAG_FIT_fast := $(DIAG_FAST)
DIAG_FIT_fast-endtoend := $(DIAG_FAST) --finetune
$(foreach v,fast fast-endtoend,$(eval $(call DIAG_FIT,global,$(v))))
$(foreach v,fast fast-endtoend,$(eval $(call DIAG_PAPER,global,$(v))))
$(eval $(call ACC_PREDICT,$(P),val))
DECODER_PREDS := $(foreach v,frozen fast fast-endtoend,$(foreach t,val train,$(DG)/pred_img_global-$(v)_s0_on_$(t).npz))
DECODER_PAPER_PREDS := $(foreach i,img_global_s0 img_global-fast_s0 img_global-fast-endtoend_s0,$(foreach t,val train,$(P)/pred_$(i)_on_$(t).npz))
ORACLE = $(PYTHON) decoder_oracle.py $(A)/search/train.npz --epochs 30
ORACLE_RUNS := "--code scan --width 32" "--code scan --width 128" \
  "--code answer --width 32 --val $(A)/split/val.npz" "--code answer --width 128 --val $(A)/split/val.npz" \
  "--code answer --width 16 --lr 1e-2 --alpha-power 0.5 --val $(A)/split/val.npz"
.PHONY: decoder
decoder: $(DGR)/decoder.md $(DGR)/decoder-paper.md $(DGR)/decoder-oracle.txt
$(DGR)/decoder-oracle.txt: decoder_oracle.py $(A)/search/train.npz $(A)/split/val.npz
	@mkdir -p $(@D)
	for a in $(ORACLE_RUNS); do echo "# $(ORACLE) $$a"; \
	  $(ORACLE) $$a || exit 1; done > $@.part && mv $@.part $@
$(DG)/val.npz: | $(A)/split/val.npz
	@mkdir -p $(@D)
	ln -sf ../split/val.npz $@
$(DG)/train.npz: | $(A)/search/train.npz
	@mkdir -p $(@D)
	ln -sf ../search/train.npz $@
$(eval $(call ACC_PREDICT,$(DG),val))
$(eval $(call ACC_PREDICT,$(DG),train))
DIAG_PREDS := $(foreach m,$(DIAG_MODELS),$(foreach v,$(DIAG_VARIANTS),$(foreach t,val train,$(DG)/pred_img_$(m)-$(v)_s0_on_$(t).npz)))
DIAG_LONG_PREDS := $(foreach m,$(DIAG_MODELS),$(foreach t,val train,$(P)/pred_img_$(m)-long_s0_on_$(t).npz))
.PHONY: diagnose
diagnose: $(DGR)/diagnose.md $(DGR)/capacity.md
# a diagnosis table: $(1) its name, $(2) its predictions
define DIAG_TABLE
$(DGR)/$(1).md: $(2)
	@mkdir -p $$(@D)
	$(LESS) metrics $$^ --summary-only --format jsonl > $(DGR)/$(1).jsonl
	$(PYTHON) headline.py $(DGR)/$(1).jsonl --no-paper > $$@.part && mv $$@.part $$@
endef
$(eval $(call DIAG_TABLE,diagnose,$(DIAG_PREDS)))
$(eval $(call DIAG_TABLE,capacity,$(DIAG_LONG_PREDS)))
$(eval $(call DIAG_TABLE,decoder,$(DECODER_PREDS)))
$(eval $(call DIAG_TABLE,decoder-paper,$(DECODER_PAPER_PREDS)))
# can each model of the paper's pair (and global-taxel) fit its own training scans in the paper's regime?
# `make -C examples fit -j2 ACC_TIER=winkler` -> results/diagnose-<tier>/fit.md: the seed-0 representation
# trained end to end for 100 epochs, the decoder at the search's faster level (lr 1e-2, power 0.5, width 16)
# and the recurrent encoder at its own lower rate (image.encoder_lr; at 1e-2 it does not learn), scored on
# its own training scans and its validation scans (not its test scans)
# and what one `global` state holds (state_probe.py: its memory of the scan, a linear probe for the inclusion),
# after the config's 20 epochs of self-supervision and after ten times as many -> results/diagnose-<tier>/state-probe.txt
$(P)/rep_global-ssl200_s0.pt: $(P)/train.npz $(P)/val.npz $(FCFG)/global.toml
	$(LESS) pretrain $(P)/train.npz --val $(P)/val.npz -o $@ --model global --seed 0 --device $(DEVICE) \
	  $$($(PYTHON) tune.py args $(FCFG)/global.toml pretrain) --epochs 200 --format jsonl > $@.json
$(DGR)/state-probe.txt: state_probe.py $(P)/rep_global_s0.pt $(P)/rep_global-ssl200_s0.pt
	@mkdir -p $(@D)
	for r in $(filter %.pt,$^); do $(PYTHON) state_probe.py $$r $(P)/train.npz $(P)/val.npz || exit 1; \
	  done > $@.part && mv $@.part $@
FIT_MODELS := less global global-taxel
DIAG_FIT_fit := $(DIAG_FAST) --finetune --epochs $(DIAG_LONG_EPOCHS) --set image.encoder_lr=3e-3
$(foreach m,$(FIT_MODELS),$(eval $(call DIAG_PAPER,$(m),fit)))
FIT_PREDS := $(foreach m,$(FIT_MODELS),$(foreach t,val train,$(P)/pred_img_$(m)-fit_s0_on_$(t).npz))
.PHONY: fit
fit: $(DGR)/fit.md $(DGR)/state-probe.txt
$(eval $(call DIAG_TABLE,fit,$(FIT_PREDS)))
# learnt or memorised? each end-to-end imager of the headline's paper regime at its last epoch (the loop's
# <stem>.last.pt, kept beside the checkpoint chosen on validation; labelled by argmax, as it carries no rule
# chosen on validation), on its own training scans and its validation scans (not its test scans):
# `make -C examples last ACC_TIER=winkler` -> results/diagnose-<tier>/last.md
LAST_MODELS := less global global-taxel
define LAST_LINK
$(P)/img_$(1)-last_s$(2).pt: $(P)/img_$(1)_s$(2).pt
	ln -sf img_$(1)_s$(2).last.pt $$@
endef
$(foreach m,$(LAST_MODELS),$(foreach s,$(SEEDS),$(eval $(call LAST_LINK,$(m),$(s)))))
LAST_PREDS := $(foreach m,$(LAST_MODELS),$(foreach s,$(SEEDS),$(foreach t,val train,$(P)/pred_img_$(m)-last_s$(s)_on_$(t).npz)))
.PHONY: last
last: $(DGR)/last.md
$(eval $(call DIAG_TABLE,last,$(LAST_PREDS)))
# is the budget what keeps global-taxel under 0.8 on its training scans? its config's end-to-end fit for
# 100 epochs instead of 50, seeds 1 and 2 (still learning at epoch 50; seed 0's 100-epoch point is fit.md's),
# on its own training scans and its validation scans: `make -C examples longer -j2 ACC_TIER=winkler`
# -> results/diagnose-<tier>/longer.md (the second run's question, asked before the global decoder's input norm;
# with it every seed fits its training scans in 50 epochs)
LONGER_SEEDS := 1 2
define LONGER_FIT
$(P)/img_global-taxel-e100_s$(1).pt: $(P)/rep_global-taxel_s$(1).pt
	$(LESS) image fit $(P)/train.npz --val $(P)/val.npz --rep $$< -o $$@ --dim 3 --seed $(1) --device $(DEVICE) \
	  $$$$($(PYTHON) tune.py args $(CFG)/global-taxel.toml fit) --epochs 100 --format jsonl > $$@.json
endef
$(foreach s,$(LONGER_SEEDS),$(eval $(call LONGER_FIT,$(s))))
LONGER_PREDS := $(foreach s,$(LONGER_SEEDS),$(foreach t,val train,$(P)/pred_img_global-taxel-e100_s$(s)_on_$(t).npz))
.PHONY: longer
longer: $(DGR)/longer.md
$(eval $(call DIAG_TABLE,longer,$(LONGER_PREDS)))

# ---------------------------------------------------------------- the paper's scan density
#   make -C examples density -j2 [ACC_TIER=winkler]      -> results/density-<tier>/density.md
# The authors palpated every insert at every orientation many times (3372 scans, each with its own random
# sensor yaw and grid jitter), so their split by scan file puts a held-out scan's insert in training at the
# same orientation; the paper's regime above has one scan per insert and orientation (168 training scans).
# Here the paper's set is palpated again (scene seeds 1-7: other yaw, jitter, surface and noise) and the
# paper's pair and the taxel pair (each with its config, seed 0) are trained on the regime's training scans plus
#   n<N>-same: re-palpations of the training scans' own insert-orientation pairs (pairs.py): a validation
#              scan's insert sits in training at other orientations only, as in the regime above;
#   n<N>-all:  re-palpations of all 240 pairs, the paper's density: a validation scan's insert sits in
#              training at its own orientation, palpated otherwise;
# scored on the regime's validation scans (not its test scans) and on its 168 training scans.
DN  := $(A)/density
DNR := results/density-$(ACC_TIER)
DENSITY_MODELS ?= global less global-taxel less-taxel
DENSITY_RE := 1 2 3 4 5 6 7
$(foreach r,$(DENSITY_RE),$(eval ACC_SIM_paper-r$(r) := $(ACC_SIM_paper) --seed $(r)))
$(DN)/same-r%.npz: $(A)/paper-r%.npz $(P)/train.npz pairs.py
	@mkdir -p $(@D)
	$(PYTHON) pairs.py $< --of $(P)/train.npz -o $@ > /dev/null
# the first $(2) re-palpations of the training pairs ($(1) = same) or of every pair ($(1) = all)
density_re = $(foreach r,$(wordlist 1,$(2),$(DENSITY_RE)),$(if $(filter same,$(1)),$(DN)/same-r$(r).npz,$(A)/paper-r$(r).npz))
DENSITY_n336-same  := $(call density_re,same,1)
DENSITY_n672-same  := $(call density_re,same,3)
DENSITY_n1344-same := $(call density_re,same,7)
DENSITY_n408-all   := $(call density_re,all,1)
DENSITY_n888-all   := $(call density_re,all,3)
DENSITY_n1848-all  := $(call density_re,all,7)
# every model's variants, or one model's own (DENSITY_VARIANTS_<model>): the paper's 8 scans per pair
# (n1344, n1848) for `global` only, where `less`'s would not fit the 2-core budget; the taxel pair
# (`less-taxel`, `global-taxel`) at the paper's split only
DENSITY_VARIANTS ?= n168 n336-same n408-all n672-same n888-all
DENSITY_VARIANTS_global ?= $(DENSITY_VARIANTS) n1344-same n1848-all
DENSITY_VARIANTS_global-taxel ?= n168 n408-all n888-all
DENSITY_VARIANTS_less-taxel ?= n168 n408-all n888-all
density_variants = $(or $(DENSITY_VARIANTS_$(1)),$(DENSITY_VARIANTS))
$(DN)/train-n168.npz: | $(P)/train.npz
	@mkdir -p $(@D)
	ln -sf ../paper/train.npz $@
$(foreach v,$(filter-out n168,$(sort $(foreach m,$(DENSITY_MODELS),$(call density_variants,$(m))))),$(eval \
  $(DN)/train-$(v).npz: $(P)/train.npz $(DENSITY_$(v)) ; $(LESS) concat $$^ -o $$@ > /dev/null))
$(DN)/val.npz $(DN)/train.npz: $(DN)/%.npz: | $(P)/val.npz $(P)/train.npz
	@mkdir -p $(@D)
	ln -sf ../paper/$*.npz $@
$(foreach m,$(DENSITY_MODELS),$(foreach v,$(call density_variants,$(m)),$(eval $(call STUDY_TRAIN,$(DN),$(m),$(v),$(DN)/train-$(v).npz,$(DN)/val.npz,$(CFG)))))
$(eval $(call ACC_PREDICT,$(DN),val))
$(eval $(call ACC_PREDICT,$(DN),train))
DENSITY_VAL   := $(foreach m,$(DENSITY_MODELS),$(foreach v,$(call density_variants,$(m)),$(DN)/pred_img_$(m)-$(v)_s0_on_val.npz))
DENSITY_PREDS := $(DENSITY_VAL) $(DENSITY_VAL:_on_val.npz=_on_train.npz)
# curves.png: the imaging fits at the paper's split (n168 and the -all variants), one colour each
DENSITY_PLOT  := $(filter-out %-same_s0_on_val.npz,$(DENSITY_VAL))
.PHONY: density
density: $(DENSITY_PREDS)
	@mkdir -p $(DNR)
	$(LESS) metrics $^ --baseline-from $(P)/train.npz --summary-only --format jsonl > $(DNR)/density.jsonl
	$(call STUDY_TIMES,$(DENSITY_VAL),$(DNR)/times.jsonl)
	$(PYTHON) headline.py $(DNR)/density.jsonl --no-paper --times $(DNR)/times.jsonl > $(DNR)/density.md.part \
	  && mv $(DNR)/density.md.part $(DNR)/density.md
	$(LESS) plot log $(patsubst $(DN)/pred_%_on_val.npz,$(DN)/%.log.jsonl,$(DENSITY_PLOT)) -o $(DNR)/curves.png \
	  $(foreach p,$(DENSITY_PLOT),--label $(patsubst pred_img_%_s0_on_val.npz,%,$(notdir $(p)))) > /dev/null
