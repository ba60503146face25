/PROG  RVIS_MBX
/ATTR
OWNER		= MNEDITOR;
COMMENT		= "rvis Modbus mailbox";
PROTECT		= READ_WRITE;
TCD:  STACK_SIZE	= 0,
      TASK_PRIORITY	= 50,
      TIME_SLICE	= 0,
      BUSY_LAMP_OFF	= 0,
      ABORT_REQUEST	= 0,
      PAUSE_REQUEST	= 0;
DEFAULT_GROUP	= 1,*,*,*,*;
/MN
   1:  !rvis mailbox over Modbus TCP ;
   2:  !app: R1 CMD R2 SPEED R3-8 J1-J6 ;
   3:  !app: R9 RESET R10 ABORT ;
   4:  !TP: R11 ACK R12 DONE R13 STATUS ;
   5:  !TP: R14 ERROR R15-20 CURRENT ;
   6:  !STATUS 0 idle 1 moving 2 fault ;
   7:  R[11:ACK]=R[1:CMD]    ;
   8:  R[13:STATUS]=0    ;
   9:  CALL RVIS_CUR    ;
  10:  LBL[1] ;
  11:  WAIT (R[1:CMD]<>R[11:ACK])    ;
  12:  R[11:ACK]=R[1:CMD]    ;
  13:  IF (R[13:STATUS]=2),JMP LBL[1] ;
  14:  IF (R[2:SPEED]<=0 OR R[2:SPEED]>100),JMP LBL[90] ;
  15:  PR[90:RVIS TARGET]=JPOS    ;
  16:  PR[90,1:RVIS TARGET]=R[3:J1]    ;
  17:  PR[90,2:RVIS TARGET]=R[4:J2]    ;
  18:  PR[90,3:RVIS TARGET]=R[5:J3]    ;
  19:  PR[90,4:RVIS TARGET]=R[6:J4]    ;
  20:  PR[90,5:RVIS TARGET]=R[7:J5]    ;
  21:  PR[90,6:RVIS TARGET]=R[8:J6]    ;
  22:  R[13:STATUS]=1    ;
  23:J PR[90:RVIS TARGET] R[2:SPEED]% FINE    ;
  24:  CALL RVIS_CUR    ;
  25:  R[13:STATUS]=0    ;
  26:  R[12:DONE]=R[11:ACK]    ;
  27:  JMP LBL[1] ;
  28:  LBL[90:BAD SPEED] ;
  29:  R[14:ERROR]=18    ;
  30:  R[13:STATUS]=2    ;
  31:  JMP LBL[1] ;
/POS
/END
