//! The C functions of PETSc (3.18) that the backend calls, declared by hand.
//!
//! Why by hand and not bindgen: the backend uses about forty functions of PETSc's C API, all
//! with plain C types (opaque object pointers, `int`, `double`, C strings). Declaring them here
//! keeps the build free of libclang and of a generated file of tens of thousands of lines, and
//! each declaration can be checked against `petsc*.h` by reading. What can differ between
//! PETSc builds is checked by `build.rs` against `petscconf.h` before anything is compiled:
//!
//! * `PetscScalar` and `PetscReal` are `f64` (a real, double-precision build:
//!   `PETSC_USE_REAL_DOUBLE`, no `PETSC_USE_COMPLEX`), otherwise the build stops;
//! * `PetscInt` is `i32`, or `i64` when PETSc has `PETSC_USE_64BIT_INDICES` (`cfg(petsc_int64)`);
//! * `MPI_Comm` is OpenMPI's (a pointer; `MPI_COMM_SELF` is the address of the library symbol
//!   `ompi_mpi_comm_self`): build.rs links OpenMPI through `ompi.pc` and stops without it.
//!
//! Enumerations (`PetscBool`, `KSPConvergedReason`, `KSPNormType`, `PCSide`, `PetscErrorType`)
//! are C enums, the size of `int`; their values are copied from the headers. Every function
//! returns a `PetscErrorCode` (`int`, 0 on success), which `super::check` turns into an error
//! naming the function.

#![allow(non_camel_case_types, non_snake_case, clippy::upper_case_acronyms)]

use std::ffi::{c_char, c_int, c_void};

/// PETSc's index type (`PetscInt`).
#[cfg(not(petsc_int64))]
pub type PetscInt = i32;
/// PETSc's index type (`PetscInt`, 64-bit indices).
#[cfg(petsc_int64)]
pub type PetscInt = i64;
/// `PetscScalar` of a real, double-precision build (checked by build.rs).
pub type PetscScalar = f64;
/// `PetscReal` of a double-precision build.
pub type PetscReal = f64;
/// `PetscErrorCode`: 0 on success.
pub type PetscErrorCode = c_int;
/// `PetscBool` (`PETSC_FALSE`, `PETSC_TRUE`).
pub type PetscBool = c_int;
pub const PETSC_FALSE: PetscBool = 0;
pub const PETSC_TRUE: PetscBool = 1;
/// `PETSC_DEFAULT`: keep the current value (`KSPSetTolerances`).
pub const PETSC_DEFAULT: c_int = -2;

/// `KSPConvergedReason`: positive converged, negative diverged.
pub type KSPConvergedReason = c_int;
/// `KSPNormType`.
pub type KSPNormType = c_int;
pub const KSP_NORM_UNPRECONDITIONED: KSPNormType = 2;
/// `PETSC_DECIDE`: let PETSc choose a size (`VecCreateMPI`'s local size).
#[cfg(feature = "mpi")]
pub const PETSC_DECIDE: PetscInt = -1;
/// `InsertMode`.
#[cfg(feature = "mpi")]
pub type InsertMode = c_int;
#[cfg(feature = "mpi")]
pub const INSERT_VALUES: InsertMode = 1;
#[cfg(feature = "mpi")]
pub const ADD_VALUES: InsertMode = 2;
/// `ScatterMode`.
#[cfg(feature = "mpi")]
pub type ScatterMode = c_int;
#[cfg(feature = "mpi")]
pub const SCATTER_FORWARD: ScatterMode = 0;
/// `MatAssemblyType`.
#[cfg(feature = "mpi")]
pub type MatAssemblyType = c_int;
#[cfg(feature = "mpi")]
pub const MAT_FINAL_ASSEMBLY: MatAssemblyType = 0;
/// `NormType`.
#[cfg(feature = "mpi")]
pub type NormType = c_int;
#[cfg(feature = "mpi")]
pub const NORM_2: NormType = 1;
/// `PCSide`.
pub type PCSide = c_int;
pub const PC_RIGHT: PCSide = 1;
/// `PetscErrorType`: the first call of the error handler for an error is `PETSC_ERROR_INITIAL`,
/// the calls that follow up the stack `PETSC_ERROR_REPEAT`.
pub type PetscErrorType = c_int;
pub const PETSC_ERROR_INITIAL: PetscErrorType = 0;

/// An opaque PETSc object (`struct _p_Mat` and the like).
#[repr(C)]
pub struct Opaque {
    _private: [u8; 0],
}
pub type Mat = *mut Opaque;
pub type Vec = *mut Opaque;
pub type KSP = *mut Opaque;
pub type PC = *mut Opaque;
pub type MatNullSpace = *mut Opaque;
/// `VecScatter` (a `PetscSF`).
#[cfg(feature = "mpi")]
pub type VecScatter = *mut Opaque;
#[cfg(feature = "mpi")]
pub type IS = *mut Opaque;
#[cfg(feature = "mpi")]
pub type PetscCopyMode = c_int;
#[cfg(feature = "mpi")]
pub const PETSC_COPY_VALUES: PetscCopyMode = 0;
/// `PetscOptions`; null is the global options database.
pub type PetscOptions = *mut Opaque;
/// OpenMPI's `MPI_Comm` (`struct ompi_communicator_t *`).
pub type MPI_Comm = *mut Opaque;

/// `PetscPushErrorHandler`'s handler:
/// `(comm, line, function, file, code, type, message, context) -> code`.
pub type ErrorHandler = unsafe extern "C" fn(
    MPI_Comm,
    c_int,
    *const c_char,
    *const c_char,
    PetscErrorCode,
    PetscErrorType,
    *const c_char,
    *mut c_void,
) -> PetscErrorCode;

unsafe extern "C" {
    /// OpenMPI's predefined communicator behind `MPI_COMM_SELF`.
    static ompi_mpi_comm_self: Opaque;
    /// OpenMPI's predefined communicator behind `MPI_COMM_WORLD` (`PETSC_COMM_WORLD` unless
    /// set otherwise: all processes of the run).
    #[cfg(feature = "mpi")]
    static ompi_mpi_comm_world: Opaque;

    pub fn PetscInitializeNoArguments() -> PetscErrorCode;
    pub fn PetscOptionsSetValue(
        options: PetscOptions,
        name: *const c_char,
        value: *const c_char,
    ) -> PetscErrorCode;
    pub fn PetscOptionsInsertString(options: PetscOptions, text: *const c_char) -> PetscErrorCode;
    pub fn PetscOptionsPrefixPush(options: PetscOptions, prefix: *const c_char) -> PetscErrorCode;
    pub fn PetscOptionsPrefixPop(options: PetscOptions) -> PetscErrorCode;
    pub fn PetscOptionsHasName(
        options: PetscOptions,
        prefix: *const c_char,
        name: *const c_char,
        set: *mut PetscBool,
    ) -> PetscErrorCode;
    pub fn PetscOptionsLeftGet(
        options: PetscOptions,
        count: *mut PetscInt,
        names: *mut *mut *mut c_char,
        values: *mut *mut *mut c_char,
    ) -> PetscErrorCode;
    pub fn PetscOptionsLeftRestore(
        options: PetscOptions,
        count: *mut PetscInt,
        names: *mut *mut *mut c_char,
        values: *mut *mut *mut c_char,
    ) -> PetscErrorCode;
    pub fn PetscPushErrorHandler(handler: ErrorHandler, context: *mut c_void) -> PetscErrorCode;
    pub fn PetscErrorMessage(
        code: c_int,
        text: *mut *const c_char,
        specific: *mut *mut c_char,
    ) -> PetscErrorCode;

    pub fn MatCreate(comm: MPI_Comm, matrix: *mut Mat) -> PetscErrorCode;
    pub fn MatSetSizes(
        matrix: Mat,
        local_rows: PetscInt,
        local_cols: PetscInt,
        rows: PetscInt,
        cols: PetscInt,
    ) -> PetscErrorCode;
    pub fn MatSetBlockSize(matrix: Mat, size: PetscInt) -> PetscErrorCode;
    pub fn MatSetType(matrix: Mat, kind: *const c_char) -> PetscErrorCode;
    pub fn MatSeqAIJSetPreallocationCSR(
        matrix: Mat,
        row_start: *const PetscInt,
        columns: *const PetscInt,
        values: *const PetscScalar,
    ) -> PetscErrorCode;
    pub fn MatSeqAIJGetArray(matrix: Mat, values: *mut *mut PetscScalar) -> PetscErrorCode;
    pub fn MatSeqAIJRestoreArray(matrix: Mat, values: *mut *mut PetscScalar) -> PetscErrorCode;
    pub fn MatSetNearNullSpace(matrix: Mat, space: MatNullSpace) -> PetscErrorCode;
    pub fn MatDestroy(matrix: *mut Mat) -> PetscErrorCode;
    pub fn MatNullSpaceCreateRigidBody(
        coordinates: Vec,
        space: *mut MatNullSpace,
    ) -> PetscErrorCode;
    pub fn MatNullSpaceDestroy(space: *mut MatNullSpace) -> PetscErrorCode;

    pub fn VecCreateSeq(comm: MPI_Comm, size: PetscInt, vector: *mut Vec) -> PetscErrorCode;
    pub fn VecSetBlockSize(vector: Vec, size: PetscInt) -> PetscErrorCode;
    pub fn VecGetArray(vector: Vec, values: *mut *mut PetscScalar) -> PetscErrorCode;
    pub fn VecRestoreArray(vector: Vec, values: *mut *mut PetscScalar) -> PetscErrorCode;
    pub fn VecDestroy(vector: *mut Vec) -> PetscErrorCode;

    #[cfg(feature = "mpi")]
    pub fn MatMPIAIJSetPreallocationCSR(
        matrix: Mat,
        row_start: *const PetscInt,
        columns: *const PetscInt,
        values: *const PetscScalar,
    ) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn MatZeroEntries(matrix: Mat) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn MatSetValues(
        matrix: Mat,
        row_count: PetscInt,
        rows: *const PetscInt,
        column_count: PetscInt,
        columns: *const PetscInt,
        values: *const PetscScalar,
        mode: InsertMode,
    ) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn MatAssemblyBegin(matrix: Mat, kind: MatAssemblyType) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn MatAssemblyEnd(matrix: Mat, kind: MatAssemblyType) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn MatMult(matrix: Mat, x: Vec, y: Vec) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn VecCreateMPI(
        comm: MPI_Comm,
        local: PetscInt,
        global: PetscInt,
        vector: *mut Vec,
    ) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn VecSet(vector: Vec, value: PetscScalar) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn VecSetValues(
        vector: Vec,
        count: PetscInt,
        indices: *const PetscInt,
        values: *const PetscScalar,
        mode: InsertMode,
    ) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn VecAssemblyBegin(vector: Vec) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn VecAssemblyEnd(vector: Vec) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn VecAYPX(y: Vec, alpha: PetscScalar, x: Vec) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn VecNorm(vector: Vec, kind: NormType, norm: *mut PetscReal) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn VecScatterCreateToAll(
        vector: Vec,
        scatter: *mut VecScatter,
        gathered: *mut Vec,
    ) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn VecScatterBegin(
        scatter: VecScatter,
        from: Vec,
        to: Vec,
        mode: InsertMode,
        direction: ScatterMode,
    ) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn VecScatterEnd(
        scatter: VecScatter,
        from: Vec,
        to: Vec,
        mode: InsertMode,
        direction: ScatterMode,
    ) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn VecScatterCreate(
        from: Vec,
        from_indices: IS,
        to: Vec,
        to_indices: IS,
        scatter: *mut VecScatter,
    ) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn ISCreateGeneral(
        comm: MPI_Comm,
        count: PetscInt,
        indices: *const PetscInt,
        mode: PetscCopyMode,
        set: *mut IS,
    ) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn ISDestroy(set: *mut IS) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn MatSetUp(matrix: Mat) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn MatPreallocatorPreallocate(
        preallocator: Mat,
        fill: PetscBool,
        matrix: Mat,
    ) -> PetscErrorCode;
    #[cfg(feature = "mpi")]
    pub fn VecScatterDestroy(scatter: *mut VecScatter) -> PetscErrorCode;

    pub fn KSPCreate(comm: MPI_Comm, ksp: *mut KSP) -> PetscErrorCode;
    pub fn KSPSetOperators(ksp: KSP, matrix: Mat, preconditioning: Mat) -> PetscErrorCode;
    pub fn KSPSetType(ksp: KSP, kind: *const c_char) -> PetscErrorCode;
    pub fn KSPGetType(ksp: KSP, kind: *mut *const c_char) -> PetscErrorCode;
    pub fn KSPGetPC(ksp: KSP, pc: *mut PC) -> PetscErrorCode;
    pub fn PCSetType(pc: PC, kind: *const c_char) -> PetscErrorCode;
    pub fn PCGetType(pc: PC, kind: *mut *const c_char) -> PetscErrorCode;
    pub fn KSPSetTolerances(
        ksp: KSP,
        relative: PetscReal,
        absolute: PetscReal,
        divergence: PetscReal,
        max_iterations: PetscInt,
    ) -> PetscErrorCode;
    pub fn KSPGetTolerances(
        ksp: KSP,
        relative: *mut PetscReal,
        absolute: *mut PetscReal,
        divergence: *mut PetscReal,
        max_iterations: *mut PetscInt,
    ) -> PetscErrorCode;
    pub fn KSPSetNormType(ksp: KSP, norm: KSPNormType) -> PetscErrorCode;
    pub fn KSPSetPCSide(ksp: KSP, side: PCSide) -> PetscErrorCode;
    pub fn KSPSetOptionsPrefix(ksp: KSP, prefix: *const c_char) -> PetscErrorCode;
    pub fn KSPSetFromOptions(ksp: KSP) -> PetscErrorCode;
    pub fn KSPSolve(ksp: KSP, rhs: Vec, solution: Vec) -> PetscErrorCode;
    pub fn KSPGetIterationNumber(ksp: KSP, iterations: *mut PetscInt) -> PetscErrorCode;
    pub fn KSPGetConvergedReason(ksp: KSP, reason: *mut KSPConvergedReason) -> PetscErrorCode;
    pub fn KSPGetConvergedReasonString(ksp: KSP, text: *mut *const c_char) -> PetscErrorCode;
    pub fn KSPDestroy(ksp: *mut KSP) -> PetscErrorCode;
}

/// `PETSC_COMM_SELF` (`MPI_COMM_SELF` under OpenMPI: the address of `ompi_mpi_comm_self`).
pub fn comm_self() -> MPI_Comm {
    (&raw const ompi_mpi_comm_self).cast_mut()
}

/// `MPI_COMM_WORLD` under OpenMPI: every process of the run.
#[cfg(feature = "mpi")]
pub fn comm_world() -> MPI_Comm {
    (&raw const ompi_mpi_comm_world).cast_mut()
}
