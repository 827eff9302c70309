//! Build script: nothing in the default build. With the `petsc` feature it finds PETSc and
//! OpenMPI through pkg-config (`PETSc.pc`, `ompi.pc`), links them, and checks that PETSc was
//! configured the way the hand-written FFI (`src/solver/petsc/ffi.rs`) declares it: real,
//! double-precision scalars, and a `PetscInt` of 32 bits (or 64, then the FFI is compiled with
//! `cfg(petsc_int64)`). A mismatch stops the build with what was found, instead of a binary
//! that passes wrong-sized integers to PETSc.

fn main() {
    println!("cargo::rerun-if-changed=build.rs");
    println!("cargo::rustc-check-cfg=cfg(petsc_int64)");
    #[cfg(feature = "petsc")]
    if let Err(why) = petsc::configure() {
        eprintln!("error: the `petsc` feature cannot be built: {why}");
        std::process::exit(1);
    }
}

#[cfg(feature = "petsc")]
mod petsc {
    use std::path::PathBuf;

    /// Finds and links PETSc and MPI; checks PETSc's configuration against the FFI.
    pub fn configure() -> Result<(), String> {
        let petsc = pkg_config::Config::new()
            .atleast_version("3.18")
            .probe("PETSc")
            .map_err(|e| {
                format!(
                    "PETSc >= 3.18 not found through pkg-config ({e}); on Debian or Ubuntu: \
                     apt-get install libpetsc-real-dev libopenmpi-dev (or set PKG_CONFIG_PATH \
                     to the folder of a PETSc build's PETSc.pc)"
                )
            })?;
        // The FFI takes MPI_COMM_SELF as OpenMPI defines it (the address of a library symbol),
        // so it links libmpi itself.
        pkg_config::Config::new().probe("ompi").map_err(|e| {
            format!(
                "OpenMPI not found through pkg-config ({e}); the PETSc FFI supports OpenMPI's \
                 MPI_Comm only (Debian's MPI): apt-get install libopenmpi-dev"
            )
        })?;
        let config = petsc
            .include_paths
            .iter()
            .map(|dir| dir.join("petscconf.h"))
            .find(|file| file.is_file())
            .ok_or_else(|| {
                format!(
                    "petscconf.h not found in PETSc's include folders {:?}",
                    petsc.include_paths
                )
            })?;
        check_configuration(&config)
    }

    /// The defines of `petscconf.h` that fix the FFI's types.
    fn check_configuration(config: &PathBuf) -> Result<(), String> {
        println!("cargo::rerun-if-changed={}", config.display());
        let text = std::fs::read_to_string(config)
            .map_err(|e| format!("cannot read {}: {e}", config.display()))?;
        let defined = |name: &str| {
            text.lines().any(|line| {
                let mut words = line.split_whitespace();
                words.next() == Some("#define") && words.next() == Some(name)
            })
        };
        if defined("PETSC_USE_COMPLEX") || !defined("PETSC_USE_REAL_DOUBLE") {
            return Err(format!(
                "{} is not a real, double-precision PETSc (PETSC_USE_REAL_DOUBLE without \
                 PETSC_USE_COMPLEX); the FFI passes f64 as PetscScalar: use libpetsc-real-dev",
                config.display()
            ));
        }
        if defined("PETSC_USE_64BIT_INDICES") {
            println!("cargo::rustc-cfg=petsc_int64");
        }
        Ok(())
    }
}
