MODULE DroidEGM
    !***********************************************************************************
    ! DroidEGM -- the robot controller's side of a DROID ABB subunit (issue 26; docs/abb.md).
    !
    ! Load this module into the motion task (T_ROB1) of an IRC5 or OmniCore with the
    ! "Externally Guided Motion" option (689-1 on IRC5, 3124-1 on OmniCore) and run main.
    ! It lets the PC running droid-egm guide the arm joint by joint:
    !   * the controller streams EgmRobot (feedback, planned, motor/RAPID/MCI state) every
    !     4 ms to the UDP device named below, whether or not it is being guided;
    !   * droid-egm answers each one with EgmSensor joint targets [deg];
    !   * EGMRunJoint follows them until droid-egm has been silent for CommTimeout; the
    !     loop below then waits RESTART_S and starts guidance again from where the arm
    !     stands -- as droid-sim's abb_egm twin models it (droid/sim/abb/controller.py).
    !
    ! Controller configuration (Communication > Transmission Protocol, type UDPUC):
    !   name "DROID_EGM", remote address = the droid-egm PC's address, remote port = the
    !   port of the subunit's egm key in the cell file (cells/abb_weld.toml: 6510).
    !
    ! NOT TESTED ON A CONTROLLER: nothing in DROID's test environment runs RAPID.  The
    ! instruction names and arguments follow ABB's "Application manual - Externally Guided
    ! Motion" (EGMGetId, EGMSetupUC, EGMActJoint, EGMStreamStart, EGMRunJoint, EGMReset);
    ! check them against the manual of the RobotWare/RobotWare 7 version you run, and try it
    ! in RobotStudio's virtual controller first, at low speed, with the enabling device.
    !***********************************************************************************

    ! The EGM process and its identity.
    LOCAL VAR egmident egm_id;
    LOCAL VAR egmstate egm_state;

    ! Convergence band per joint [deg]: EGMRunJoint counts the arm "on target" inside it.
    ! droid-sim's twin uses the same +-0.1 deg (its convergence_deg option).
    LOCAL CONST egm_minmax egm_band := [-0.1, 0.1];

    ! Communication timeout [s]: guidance ends when droid-egm has been silent this long
    ! (ABB's default is 1 s; the twin's comm_timeout_s).
    LOCAL CONST num COMM_TIMEOUT_S := 1;

    ! Pause before guidance starts again after a timeout [s] (the twin's restart_s).
    LOCAL CONST num RESTART_S := 0.2;

    ! How long one EGMRunJoint runs before the loop renews it [s]: long, so the arm is
    ! guided without gaps; the loop starts the next one at once.
    LOCAL CONST num RUN_S := 3600;

    ! Maximum deviation of the sensor's target from the current position [deg] that
    ! EGM accepts before it stops with an error (a guard against a wild target).
    LOCAL CONST num MAX_POS_DEV_DEG := 100;

    ! Maximum speed deviation [deg/s] EGM allows between the sensor's stream and its own
    ! path (well above the arm's joint speeds: droid-egm already respects them).
    LOCAL CONST num MAX_SPEED_DEV_DEG_S := 500;

    PROC main()
        ! Identify and configure EGM once: joint mode, UDP unicast to DROID_EGM.
        EGMReset egm_id;
        EGMGetId egm_id;
        egm_state := EGMGetState(egm_id);
        EGMSetupUC ROB_1, egm_id, "default", "DROID_EGM" \Joint \CommTimeout:=COMM_TIMEOUT_S;

        ! Joint guidance with the convergence band on every axis; no low-pass filter of
        ! our own (droid-egm interpolates the planner's way-points already).
        EGMActJoint egm_id
            \J1:=egm_band \J2:=egm_band \J3:=egm_band
            \J4:=egm_band \J5:=egm_band \J6:=egm_band
            \MaxPosDeviation:=MAX_POS_DEV_DEG
            \MaxSpeedDeviation:=MAX_SPEED_DEV_DEG_S;

        ! Feedback streams from now on, guided or not: droid-egm sees the arm (and reports
        ! it homed) while the robot is idle, after a timeout, with the motors off.
        EGMStreamStart egm_id \SampleRate:=4;

        WHILE TRUE DO
            ! Guided motion: the targets of EgmSensor, until droid-egm falls silent.
            EGMRunJoint egm_id, EGM_STOP_HOLD \J1 \J2 \J3 \J4 \J5 \J6
                \CondTime:=RUN_S \RampInTime:=0.05 \PosCorrGain:=1;
            WaitTime RESTART_S;
        ENDWHILE

    ERROR
        ! A communication timeout (or a target outside MaxPosDeviation) ends EGMRunJoint
        ! with an error: hold still, pause, and guide again from where the arm stands.
        IF ERRNO = ERR_UDPUC_COMM THEN
            WaitTime RESTART_S;
            RETRY;
        ENDIF
        ! Anything else stops the program: EGM is reset so a restart begins clean.
        EGMReset egm_id;
        RAISE;
    ENDPROC
ENDMODULE
