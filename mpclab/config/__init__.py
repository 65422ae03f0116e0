"""Configuration and composition: the config folder and root schema (`root`), the registry of
components and their schemas derived from constructors (`registry`), which backends can
express a term or constraint (`expressible`), building nested options (`instantiate`), which
targets a config may build (`allowed_targets`) and which file set a key (`key_origin`)."""
