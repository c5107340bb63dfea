"""ngpm_compiler: the .lsys language, code generation, training and export (CLI `ngpmc`)."""
