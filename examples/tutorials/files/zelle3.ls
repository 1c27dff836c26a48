/PROG  ZELLE3
/ATTR
EIGN.		= MNEDITOR;
KOMMENTAR	= "Zelle 3 Schweissen";
PROG_GRÖßE	= 2210;
ERSTELL		= TAG 24-05-14  ZEIT 08:10:12;
GEÄNDERT	= TAG 24-05-14  ZEIT 08:12:40;
DATEI_NAME	= ZELLE3;
VERSION		= 0;
ZEILEN		= 11;
SPEICHERGR.	= 3120;
SCHUTZ		= LESEN_SCHREIB;
TCD:  STACK_GRÖßE	= 0,
      TASK_PRIORITY	= 50,
      ZEITSCHEIBE	= 0,
      BUSY_LAMP_AUS	= 0,
      ABORT_ANFRAGE	= 0,
      HALT_ANFRAGE	= 0;
DEFAULT_GRUP	= 1,1,*,*,*;
KONTROLLCODE	= 00000000 00000000;
/APPL
/MN
   1:  UFRAME_NUM=2 ;
   2:  UTOOL_NUM=3 ;
   3:J P[4] 100% FEIN    ;
   4:J P[1] 50% CNT50    ;
   5:L P[2:"Schweisspunkt"] 250mm/sek FEIN    ;
   6:  ! Zange schliessen ;
   7:  A[23]=AN ;
   8:  WARTE (E[23])    ;
   9:  //L P[3] 200mm/sek CNT0    ;
  10:L P[5] 100mm/sek CNT0    ;
  11:  AUFRUF EQEND    ;
/POS
P[1]{
   GP1:
	UF : 2, UT : 3,		KONFIG : 'N U T, 0, 0, 1',
	X =   258.162  mm,	Y =  -152.307  mm,	Z =   768.048  mm,
	W =  -145.983 deg,	P =     5.221 deg,	R =  -167.769 deg
   GP2:
	UF : 2, UT : 3,	
	J1=   100.000  mm
};
P[2:"Schweisspunkt"]{
   GP1:
	UF : 2, UT : 3,		KONFIG : 'F U T, 0, 0, 0',
	X =  -102.676  mm,	Y =  -775.158  mm,	Z =  1178.783  mm,
	W =   -52.850 deg,	P =    -5.381 deg,	R =   176.268 deg
   GP2:
	UF : 2, UT : 3,	
	J1=     0.000  mm
};
P[3]{
   GP1:
	UF : F, UT : F,		KONFIG : 'N D B, 0, 0, 0',
	X = ********  mm,	Y = ********  mm,	Z = ********  mm,
	W = ******** deg,	P = ******** deg,	R = ******** deg
};
P[4]{
   GP1:
	UF : 0, UT : 3,	
	J1=     0.000 deg,	J2=     -.500 deg,	J3=     0.000 deg,
	J4=     0.000 deg,	J5=   -90.000 deg,	J6=     0.000 deg
};
P[5]{
   GP1:
	UF : 2, UT : 3,		KONFIG : 'N U T, 0, 0, 0',
	RX =   195.754  mm,	RY =  -124.267  mm,	RZ =   922.355  mm,
	RW =  -180.000 deg,	RP =   -40.000 deg,	RR =   -25.000 deg
};
P[6]{
   GP1:
	UF : 2, UT : 3,		KONFIG : 'N U T, 0, 0, 0',
	X =   195.754  mm,	Y =  -124.267  mm,	Z =   922.355  mm,
	W =  -180.000 deg,	P =   -40.000 deg,	R =   -25.000 deg
};
/END
